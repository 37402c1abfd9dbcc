"""The per-rank DDR4 state machine of DRAMPower v6, vectorised: command trace -> CommandStats.

:func:`trace_stats` is the step's entry point (ranges checked, then :func:`command_stats`).

Rules (DRAMPower v6.2 ``DDR4Core``; DESIGN.md section 3):

- A bank is active from ACT until a precharge of it: PRE, PREA (every bank of the rank), or the
  implicit precharge of RDA at max(ACT + RAS, t + AL + RTP) and of WRA at
  max(ACT + RAS, t + BL/dataRate + WL + WR). A precharge of a bank that is already precharged is
  not counted (``pre`` counts transitions to the precharged state).
- REFA (and the refresh that starts SREFEN) makes every bank of the rank active for RFC, then
  precharges them without counting a precharge. SREFEN's self-refresh starts at t + RFC and lasts
  until SREFEX.
- Power-down entry (PDEA/PDEP) and exit (PDXA/PDXP) happen at max(t, earliest), where earliest is
  the latest of: the last ACT + RCD (or the last power-down exit that resumed an open bank + RCD),
  the last counted precharge + RP, and the end of the last refresh. In power-down no bank counts
  as active.
- Implicit events (auto-precharges, refresh ends, delayed power-down entry/exit) are executed
  before the first later command whose cycle is not earlier, in time order, as DRAMPower's
  implicit-command queue does; those after the evaluation time T never happen.

At T: ``cycles_act`` = cycles with any bank active and not in power-down, ``cycles_pdna``,
``cycles_pdnp``, ``cycles_sref``, and ``cycles_pre`` = T minus those; ``bank_active_cycles`` sums
each bank's active cycles.

Deliberate simplifications (only for sequences JEDEC forbids, documented in docs/dram-model.md): an
ACT to an open bank keeps the bank open (DRAMPower restarts the interval and drops the time so far);
the RDA/WRA precharge delay counts from the ACT even across a power-down (DRAMPower counts from the
power-down exit); PDXP after a PDEP with an open bank resumes the rank's active time (DRAMPower
waits for the next ACT). Power-down and self-refresh commands are walked one by one (Python loop
over those commands only); every other command is handled in bulk.

Example:
    >>> import tempfile, pathlib
    >>> from hdeem_watch.dram.command_trace import read_command_trace
    >>> from hdeem_watch.dram.memspec import preset
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "t.csv"
    >>> _ = path.write_text("0,ACT,0,0,3,100,0\\n15,RD,0,0,3,100,0\\n40,PRE,0,0,3,100,0\\n100,END,0,0,0,0,0\\n")
    >>> stats = trace_stats(preset("ddr4-2133-x8-4gb"), read_command_trace(path))
    >>> stats.ranks[0].act, stats.ranks[0].rd, stats.ranks[0].cycles_act, stats.ranks[0].cycles_pre
    (1.0, 1.0, 40.0, 60.0)
"""

from __future__ import annotations

import numpy as np

from hdeem_watch.dram.command_trace import CODE, DDR5_ONLY, CommandTrace, check_ranges
from hdeem_watch.dram.memspec import MemSpec
from hdeem_watch.dram.stats import CommandStats, RankStats
from hdeem_watch.errors import InputError

# bank event types
_OPEN_RESTART, _OPEN_IFNOT, _CLOSE_COUNT, _CLOSE_REF = 0, 1, 2, 3


def _ev(time: np.ndarray, key: np.ndarray, q: np.ndarray, kind: int, cls: int) -> tuple[np.ndarray, ...]:
    n = time.size
    return (time.astype(np.int64), key.astype(np.int64), q.astype(np.int64),
            np.full(n, kind, np.int8), np.full(n, cls, np.int8))


def _bank_events(spec: MemSpec, trace: CommandTrace) -> tuple[np.ndarray, ...]:
    """All bank-state events, each with (time, bank key, exec position, type, counted-pre, delta)."""
    t, cmd = trace.cycle, trace.cmd
    n, banks, end = t.size, spec.nbr_of_banks, trace.end_cycle
    tm = spec.timings

    def key(idx: np.ndarray) -> np.ndarray:
        return trace.rank[idx].astype(np.int64) * banks + trace.bank[idx]

    off_rd = tm["AL"] + tm["RTP"]
    off_wr = spec.burst_length // spec.data_rate + tm["WL"] + tm["WR"]
    every_bank = np.arange(banks, dtype=np.int64)

    act = np.flatnonzero(cmd == CODE["ACT"])
    pre = np.flatnonzero(cmd == CODE["PRE"])
    prea = np.flatnonzero(cmd == CODE["PREA"])
    ref = np.flatnonzero((cmd == CODE["REFA"]) | (cmd == CODE["SREFEN"]))
    auto = np.flatnonzero((cmd == CODE["RDA"]) | (cmd == CODE["WRA"]))

    def per_bank(idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        keys = (trace.rank[idx].astype(np.int64) * banks)[:, None] + every_bank[None, :]
        return np.repeat(idx, banks), keys.ravel()

    prea_idx, prea_key = per_bank(prea)
    ref_idx, ref_key = per_bank(ref)
    commands = [_ev(t[act], key(act), act, _OPEN_RESTART, 1), _ev(t[pre], key(pre), pre, _CLOSE_COUNT, 1),
                _ev(t[prea_idx], prea_key, prea_idx, _CLOSE_COUNT, 1),
                _ev(t[ref_idx], ref_key, ref_idx, _OPEN_IFNOT, 1)]

    # auto-precharge of RDA/WRA: max(last ACT of the bank + RAS, t + offset)
    sel = np.sort(np.concatenate([act, auto])) if auto.size else auto
    order = sel[np.argsort(key(sel), kind="stable")]
    is_act = cmd[order] == CODE["ACT"]
    pos = np.arange(order.size)
    last = np.maximum.accumulate(np.where(is_act, pos, -1)) if order.size else pos
    okey = key(order)
    valid = (last >= 0) & (okey[np.maximum(last, 0)] == okey)
    start = np.where(valid, t[order][np.maximum(last, 0)], 0)
    mine = ~is_act
    a_idx = order[mine]
    offset = np.where(cmd[a_idx] == CODE["RDA"], off_rd, off_wr)
    a_time = np.maximum(start[mine] + tm["RAS"], t[a_idx] + offset)
    implicit = [(a_time, key(a_idx), a_idx, _CLOSE_COUNT), (t[ref_idx] + spec.trfc, ref_key, ref_idx, _CLOSE_REF)]

    i_time = np.concatenate([x[0] for x in implicit]).astype(np.int64)
    i_key = np.concatenate([x[1] for x in implicit]).astype(np.int64)
    i_creator = np.concatenate([x[2] for x in implicit]).astype(np.int64)
    i_kind = np.concatenate([np.full(x[0].size, x[3], np.int8) for x in implicit])
    keep = i_time <= end
    i_time, i_key, i_creator, i_kind = i_time[keep], i_key[keep], i_creator[keep], i_kind[keep]
    i_q = np.maximum(i_creator + 1, np.searchsorted(t, i_time, side="left"))
    first = np.lexsort((i_creator, i_time))  # queue order: time, then creation
    implicit_ev = (i_time[first], i_key[first], i_q[first], i_kind[first], np.zeros(first.size, np.int8))

    parts = [implicit_ev, *commands]
    time, bkey, q, kind, cls = (np.concatenate([p[j] for p in parts]) for j in range(5))
    exec_pos = 2 * q + cls  # implicit events run before the command they precede
    order = np.argsort(bkey * (2 * n + 2) + exec_pos, kind="stable")
    time, bkey, exec_pos, kind = time[order], bkey[order], exec_pos[order], kind[order]
    is_open = kind <= _OPEN_IFNOT
    prev = np.zeros(time.size, dtype=bool)
    prev[1:] = is_open[:-1] & (bkey[1:] == bkey[:-1])
    counted = (kind == _CLOSE_COUNT) & prev
    delta = np.where(is_open & ~prev, 1, 0) - np.where(~is_open & prev, 1, 0)
    return time, bkey // banks, exec_pos, counted, delta.astype(np.int64)


def _by_rank(rank: np.ndarray, exec_pos: np.ndarray, n: int, ranks: int) -> list[np.ndarray]:
    """Indices of each rank's events, in execution order."""
    order = np.argsort(rank * (2 * n + 2) + exec_pos, kind="stable")
    bounds = np.searchsorted(rank[order], np.arange(ranks + 1))
    return [order[bounds[r]:bounds[r + 1]] for r in range(ranks)]


def _last_before(keys: np.ndarray, values: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """``values`` at the last ``keys`` entry (sorted) below each query, 0 where there is none."""
    j = np.searchsorted(keys, queries) - 1
    if not keys.size:
        return np.zeros(queries.size, dtype=np.int64)
    return np.where(j >= 0, values[np.maximum(j, 0)], 0)


def command_stats(spec: MemSpec, trace: CommandTrace) -> CommandStats:
    """Per-rank counts and residency (see the module docstring); ranks and banks must be in range.

    Raises:
        InputError: PDXA/PDXP/SREFEX without the matching entry, or an entry while already in
            power-down or self-refresh (with the line number).
    """
    t, cmd = trace.cycle, trace.cmd
    n, ranks, end = t.size, spec.nbr_of_ranks, trace.end_cycle
    tm = spec.timings
    flat = np.zeros(len(CODE) * ranks, dtype=np.int64)
    for lo in range(0, n, 1 << 20):  # in slices: bounded temporaries
        code = cmd[lo:lo + (1 << 20)].astype(np.intp) * ranks + trace.rank[lo:lo + (1 << 20)]
        flat += np.bincount(code, minlength=len(CODE) * ranks)
    counts = flat.reshape(len(CODE), ranks)

    ev_time, ev_rank, ev_pos, ev_counted, ev_delta = _bank_events(spec, trace)
    pre_counts = np.bincount(ev_rank[ev_counted], minlength=ranks)
    change = ev_delta != 0
    ch_idx = _by_rank(ev_rank[change], ev_pos[change], n, ranks)
    ch_time, ch_pos, ch_delta = ev_time[change], ev_pos[change], ev_delta[change]
    pr_idx = _by_rank(ev_rank[ev_counted], ev_pos[ev_counted], n, ranks)
    pr_time, pr_pos = ev_time[ev_counted], ev_pos[ev_counted]

    pd_codes = [CODE[c] for c in ("PDEA", "PDXA", "PDEP", "PDXP", "SREFEN", "SREFEX")]
    pd_all = np.flatnonzero(np.isin(cmd, pd_codes))
    act_all = np.flatnonzero(cmd == CODE["ACT"])
    ref_all = np.flatnonzero((cmd == CODE["REFA"]) | (cmd == CODE["SREFEN"]))

    out = []
    for r in range(ranks):
        # rank timeline of active-bank count changes, in execution (= time) order
        ci = ch_idx[r]
        times, deltas = ch_time[ci], ch_delta[ci]
        n_active = np.cumsum(deltas)
        pd_idx = pd_all[trace.rank[pd_all] == r]
        residency = {"pdna": 0, "pdnp": 0, "sref": 0}
        pd_times: list[int] = []
        pd_flags: list[int] = []
        if pd_idx.size:
            # "earliest possible power-down" ingredients just before each such command
            acts = act_all[trace.rank[act_all] == r]
            base = _last_before(acts, t[acts] + tm["RCD"], pd_idx)
            refs = ref_all[trace.rank[ref_all] == r]
            base = np.maximum(base, _last_before(refs, t[refs] + spec.trfc, pd_idx))
            pi = pr_idx[r]
            latest_pre = np.maximum.accumulate(pr_time[pi] + tm["RP"]) if pi.size else pr_time[pi]
            base = np.maximum(base, _last_before(pr_pos[pi], latest_pre, 2 * pd_idx + 1))
            active_before = _last_before(ch_pos[ci], n_active, 2 * pd_idx + 1)
            _walk_power_down(spec, trace, pd_idx, base, active_before, residency, pd_times, pd_flags)
        times = np.concatenate([times, np.asarray(pd_times, np.int64)])
        d_active = np.concatenate([deltas, np.zeros(len(pd_times), np.int64)])
        d_pd = np.concatenate([np.zeros(ci.size, np.int64), np.asarray(pd_flags, np.int64)])
        order = np.argsort(times, kind="stable")
        times, n_act, in_pd = times[order], np.cumsum(d_active[order]), np.cumsum(d_pd[order])
        dt = np.diff(times, append=end)
        awake = in_pd == 0
        cycles_act = int(dt[(n_act > 0) & awake].sum())
        bank_active = int((dt * n_act)[awake].sum())
        cycles_pre = end - cycles_act - residency["pdna"] - residency["pdnp"] - residency["sref"]
        c = counts[:, r]
        out.append(RankStats(
            act=float(c[CODE["ACT"]]), pre=float(pre_counts[r]), rd=float(c[CODE["RD"]]), wr=float(c[CODE["WR"]]),
            rda=float(c[CODE["RDA"]]), wra=float(c[CODE["WRA"]]),
            ref=float(c[CODE["REFA"]] + c[CODE["SREFEN"]]), cycles_total=float(end),
            cycles_act=float(cycles_act), cycles_pre=float(cycles_pre),
            cycles_pdna=float(residency["pdna"]), cycles_pdnp=float(residency["pdnp"]),
            cycles_sref=float(residency["sref"]), bank_active_cycles=float(bank_active)))
    return CommandStats(ranks=tuple(out))


def _walk_power_down(spec: MemSpec, trace: CommandTrace, pd_idx: np.ndarray, base: np.ndarray,
                     active_before: np.ndarray, residency: dict[str, int], pd_times: list[int],
                     pd_flags: list[int]) -> None:
    """Power-down and self-refresh intervals of one rank (a loop over those commands only)."""
    end, rcd, rfc = trace.end_cycle, spec.timings["RCD"], spec.trfc
    codes = {CODE[c]: c for c in ("PDEA", "PDXA", "PDEP", "PDXP", "SREFEN", "SREFEX")}
    mode: str | None = None  # "PDEA", "PDEP" or "SREFEN" while in that state
    since = 0
    resumed = -1  # last power-down exit that resumed an open bank (and has happened by now)
    pending: list[int] = []  # such exits still in the future (the implicit-command queue)
    for k, i in enumerate(pd_idx.tolist()):
        name = codes[int(trace.cmd[i])]
        t = int(trace.cycle[i])
        while pending and pending[0] <= t:
            resumed = pending.pop(0)
        earliest = max(int(base[k]), resumed + rcd if resumed >= 0 else 0)
        line = f"{trace.path}: line {i + 1}: {name}"
        if name in ("PDEA", "PDEP", "SREFEN"):
            if mode is not None:
                raise InputError(f"{line} while the rank is in {mode}; expected its exit first")
            mode = name
            since = t + rfc if name == "SREFEN" else max(t, earliest)
            if name != "SREFEN" and since <= end:
                pd_times.append(since)
                pd_flags.append(1)
            continue
        expected = {"PDXA": "PDEA", "PDXP": "PDEP", "SREFEX": "SREFEN"}[name]
        if mode != expected:
            raise InputError(f"{line} without a preceding {expected}"
                             + (f" (the rank is in {mode})" if mode else "") + "; expected matching entry/exit")
        mode = None
        leave = t if name == "SREFEX" else max(t, earliest)
        if since <= end:
            residency[{"PDEA": "pdna", "PDEP": "pdnp", "SREFEN": "sref"}[expected]] += max(0, min(leave, end) - since)
            if name != "SREFEX" and leave <= end:
                pd_times.append(leave)
                pd_flags.append(-1)
        if name != "SREFEX" and active_before[k] > 0:
            pending.append(leave)
    if mode is not None and since <= end:  # still in power-down / self-refresh at T
        residency[{"PDEA": "pdna", "PDEP": "pdnp", "SREFEN": "sref"}[mode]] += end - since


def trace_stats(spec: MemSpec, trace: CommandTrace) -> CommandStats:
    """Per-rank command counts and state residency of a trace (DRAMPower v6 DDR4 state machine).

    The rules are in this module's docstring.

    Raises:
        InputError: a rank or bank out of range, power-down/self-refresh commands out of order, or
            a DDR5-only command (PRESB, REFSB).
    """
    ddr5 = np.flatnonzero(np.isin(trace.cmd, [CODE[name] for name in DDR5_ONLY]))
    if ddr5.size:
        name = DDR5_ONLY[[CODE[n] for n in DDR5_ONLY].index(int(trace.cmd[ddr5[0]]))]
        raise InputError(f"{trace.path}: line {ddr5[0] + 1}: {name} is a DDR5 command; memspec "
                         f"{spec.memory_id!r} is DDR4 (expected a DDR5 memspec for this trace)")
    check_ranges(spec, trace)
    return command_stats(spec, trace)
