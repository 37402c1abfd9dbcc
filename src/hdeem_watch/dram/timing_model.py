"""Timing and refresh of a served request sequence, and its command set (vectorised core).

Used by :func:`hdeem_watch.dram.controller.simulate`, which explains the model; the row-buffer
outcomes come from :mod:`hdeem_watch.dram.row_outcomes`. :func:`plan_timing` is the part that does
not depend on when the sequence starts (refresh-free times), :func:`run_timing` adds refresh,
commands and statistics. All cycle figures
are int64. Every step is an array operation. Column commands are spaced by the column rules
(cumulative spacing ``G``); a request that needs an activation may add a lift (its bank is not
ready yet), and the lifts of the requests in between count towards the distance to the access it
waits for, so the lifts are a recurrence over the activating requests, solved by a few Jacobi
rounds on their cumulative sums (exact when no other lift lies in between, the common case).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hdeem_watch.dram.command_set import (
    Commands,
    ControllerResult,
    Timing,
    stats_from_commands,
)
from hdeem_watch.dram.mapping import Geometry
from hdeem_watch.dram.row_outcomes import Outcomes, row_outcomes
from hdeem_watch.dram.scheduler import SchedulerConfig

_MAX_ROUNDS = 8


def _by_bank(bank: np.ndarray) -> np.ndarray:
    """Stable order by bank (a radix sort on a narrow copy of the small bank index)."""
    small = bank.astype(np.int8) if bank.size and int(bank.max()) < 128 else bank
    return np.argsort(small, kind="stable")


def _sorted_keys(bank: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """``np.sort(keys)`` for ``keys = bank × 2^42 + cycle`` whose events of one bank are mostly in
    time order already: sorted by bank, checked, fully sorted only if that was not enough."""
    ordered = keys[_by_bank(bank)]
    if ordered.size > 1 and bool((ordered[1:] < ordered[:-1]).any()):
        ordered = np.sort(keys)
    return ordered


def _column_gaps(timing: Timing, rank: np.ndarray, bankgroup: np.ndarray, write: np.ndarray,
                 hidden_turnaround: int = 0) -> np.ndarray:
    """Minimum spacing of each column command after the previous one (first entry 0).

    The spacing depends on four bits (same rank, same bank group, previous and current direction):
    a 16-entry table, indexed per pair. ``hidden_turnaround`` cycles come off each read/write
    switch (never below tCCD_S). ``bankgroup`` numbers the bank groups of all ranks (unique over
    ranks), so equal bank groups imply the same rank.
    """
    n = rank.size
    gaps = np.zeros(n, dtype=np.int64)
    if n < 2:
        return gaps
    b = timing.burst
    rank_switch = max(timing.ccd_s, b + timing.rtrs + 1)  # + 1 cycle of read/write preamble
    read_to_write = max(timing.ccd_s, timing.rl + b + 2 - timing.wl - hidden_turnaround)
    table = np.zeros(16, dtype=np.int64)
    for same_rank in (0, 1):
        for same_group in (0, 1):
            if same_group and not same_rank:
                continue
            same_kind = timing.ccd_l if same_group else timing.ccd_s if same_rank else rank_switch
            write_to_read = (timing.wl + b + timing.wtr_l if same_group else
                             timing.wl + b + timing.wtr_s if same_rank else timing.wl + b + timing.rtrs - timing.rl)
            write_to_read = max(timing.ccd_s, write_to_read - hidden_turnaround)
            for prev_w in (0, 1):
                for cur_w in (0, 1):
                    gap = (same_kind if prev_w == cur_w else read_to_write if cur_w else write_to_read)
                    if same_group and prev_w and cur_w:
                        gap = timing.ccd_l_write
                    table[((same_rank * 2 + same_group) * 2 + prev_w) * 2 + cur_w] = gap
    w = write.view(np.uint8) if write.dtype == np.bool_ else write.astype(np.uint8)
    # the pair code in bytes (cheap), then one table look-up
    code = (rank[1:] == rank[:-1]).view(np.uint8) << 3
    code |= (bankgroup[1:] == bankgroup[:-1]).view(np.uint8) << 2  # bank groups are unique over ranks
    code |= w[:-1] << 1
    code |= w[1:]
    if int(table.min()) >= 0 and int(table.max()) < 256:
        gaps[1:] = table.astype(np.uint8).take(code)
    else:
        gaps[1:] = table.take(code.astype(np.intp))
    return gaps


class _Refresh:
    """Closed-form insertion of the refresh stall windows.

    Refresh ``k >= 1`` starts at real cycle ``k × tREFI`` (PREA, then REFA after tRP) and the
    traffic resumes ``S = tRP + tRFC + tRCD`` later. A virtual (refresh-free) time ``t`` maps to
    ``t + S × k(t)``, ``k(t)`` = the refreshes that started before it.
    """

    def __init__(self, timing: Timing, start: int = 0) -> None:
        self.refi = timing.refi
        self.stall = min(timing.rp + timing.rfc + timing.rcd, self.refi - 1)
        self.start = start
        # virtual time of the first refresh at or after ``start`` (none at cycle 0)
        self.first = max(self.refi, -(-start // self.refi) * self.refi) - start
        self.period = self.refi - self.stall

    def count(self, virtual: np.ndarray) -> np.ndarray:
        return np.maximum((virtual - self.first + self.period) // self.period, 0)

    def thresholds(self, last: int) -> np.ndarray:
        """Virtual times of the refreshes up to ``last``."""
        refreshes = int(self.count(np.array([last], dtype=np.int64))[0])
        return self.first + self.period * np.arange(refreshes, dtype=np.int64)

    def real(self, virtual: np.ndarray) -> np.ndarray:
        return self.start + virtual + self.stall * self.count(virtual)


@dataclass(frozen=True)
class TimingPlan:
    """The refresh-free part of the timing of one request sequence (independent of its start).

    Attributes:
        gbank, row, write: the sequence (service order).
        outcomes: its row-buffer outcomes.
        t: virtual (refresh-free) cycle of each column command.
        act_virtual: virtual activation time of each request in ``outcomes.idx``.
    """

    gbank: np.ndarray
    row: np.ndarray
    write: np.ndarray
    outcomes: Outcomes
    t: np.ndarray
    act_virtual: np.ndarray


def plan_timing(geometry: Geometry, timing: Timing, config: SchedulerConfig, policy: str, *,
                gbank: np.ndarray, row: np.ndarray, write: np.ndarray,
                outcomes: Outcomes | None = None) -> TimingPlan:
    """Row-buffer outcomes and refresh-free times of a sequence in service order (see the module doc).

    ``outcomes``: :func:`hdeem_watch.dram.row_outcomes.row_outcomes` of the sequence, if already computed.
    """
    n = gbank.size
    queue = config.read_queue
    if outcomes is None:
        outcomes = row_outcomes(geometry, config, policy, gbank=gbank, row=row)
    idx, p_safe, p_has, q = outcomes.idx, outcomes.p, outcomes.p_has, outcomes.q
    m = idx.size
    b = timing.burst

    def recovery_of(index: np.ndarray) -> np.ndarray:
        read_recovery = timing.al + timing.rtp
        return write[index] * (timing.wl + b + timing.wr - read_recovery) + read_recovery

    rank = gbank >> (geometry.banks.bit_length() - 1)
    bankgroup = gbank >> (geometry.banks_per_group.bit_length() - 1)  # unique over the ranks
    cum = _column_gaps(timing, rank, bankgroup, write, config.hidden_turnaround)
    del rank, bankgroup
    np.cumsum(cum, out=cum)
    # Each request that needs an activation may lift the column sequence: it must wait for its
    # bank (t_p + recovery + tRP + tRCD after the previous access p, and tRAS + tRP after the
    # ACT that opened p's row). Lifts of requests in between count towards that distance, so the
    # lifts are a recurrence over the activating requests; a few Jacobi rounds solve it.
    recovery_p = recovery_of(p_safe)
    cum_i = cum[idx]
    wait_p = recovery_p + (timing.rp + timing.rcd - config.hidden_bank) - (cum_i - cum[p_safe])
    wait_q = (timing.ras + timing.rp) - (cum_i - cum[q])
    rank_p, rank_q = outcomes.rank_p, outcomes.rank_q
    lam = np.maximum(np.maximum(wait_p, wait_q), 0)
    lam *= p_has
    for _ in range(_MAX_ROUNDS):
        total = np.zeros(m + 1, dtype=np.int64)
        np.cumsum(lam, out=total[1:])
        total_i = total[:-1]  # = total[rank_i]
        new_lam = np.maximum(wait_p - (total_i - total[rank_p]), wait_q - (total_i - total[rank_q]))
        np.maximum(new_lam, 0, out=new_lam)
        new_lam *= p_has
        if np.array_equal(new_lam, lam):
            break
        lam = new_lam
    # column times: the spacing plus the lifts so far (request 0 always activates: idx[0] = 0)
    t = cum
    if m:
        np.cumsum(lam, out=lam)
        t += np.repeat(lam, np.diff(idx, append=n))
    t += timing.rcd
    # activation times: as early as the bank and the queue allow, at the latest tRCD before the column
    enter = t[np.maximum(idx - queue, 0)]
    enter *= idx >= queue
    ready = np.maximum(t[q] + (timing.ras - timing.rcd), t[p_safe] + recovery_p)
    ready += timing.rp
    ready *= p_has
    act_virtual = np.minimum(np.maximum(ready, enter), t[idx] - timing.rcd)
    return TimingPlan(gbank=gbank, row=row, write=write, outcomes=outcomes, t=t, act_virtual=act_virtual)


def _lost_hits(plan: TimingPlan, refresh: _Refresh, banks_total: int) -> np.ndarray:
    """Hits whose row a refresh closed since the previous access of their bank (ascending).

    Such a hit is the first request of its bank at or after a refresh: found per (bank,
    refresh) by a search in the bank order.
    """
    n = plan.t.size
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    thresholds = refresh.thresholds(int(plan.t[-1]))
    if thresholds.size == 0:
        return np.zeros(0, dtype=np.int64)
    first = np.searchsorted(plan.t, thresholds, side="left")  # first request after each refresh
    position = plan.outcomes.bank_sorted.astype(np.int64)
    position *= n
    position += plan.outcomes.by_bank  # ascending: by bank, then by request
    queries = (np.arange(banks_total, dtype=np.int64)[:, None] * n + first[None, :]).ravel()
    found = np.searchsorted(position, queries, side="left")
    query_bank = np.repeat(np.arange(banks_total), first.size)
    inside = found < n
    found, query_bank = found[inside], query_bank[inside]
    found = found[plan.outcomes.bank_sorted[found] == query_bank]
    return np.unique(plan.outcomes.by_bank[found[plan.outcomes.hit_sorted[found]]])


def run_timing(geometry: Geometry, timing: Timing, config: SchedulerConfig, policy: str, *,
               gbank: np.ndarray, row: np.ndarray,
               column: np.ndarray | None, write: np.ndarray, start: int = 0, close_at_end: bool = False,
               plan: TimingPlan | None = None, outcomes: Outcomes | None = None,
               keep_commands: bool = True) -> ControllerResult:
    """Time a request sequence already in service order and collect its commands and statistics.

    ``start`` is the cycle the sequence starts at (a chunk after earlier ones); ``close_at_end``
    precharges the banks left open and ends the window ``tRP`` later, so the next chunk starts
    with every bank precharged. ``column`` may be ``None`` when the commands are not kept (their
    ``col_column`` is then empty). ``plan``: :func:`plan_timing` of the sequence, or ``outcomes``: its
    :func:`hdeem_watch.dram.row_outcomes.row_outcomes`, if already computed. ``keep_commands=False`` leaves ``col_cycle`` empty (the statistics do not need it).
    """
    if plan is None:
        plan = plan_timing(geometry, timing, config, policy, gbank=gbank, row=row, write=write, outcomes=outcomes)
    gbank, row, write, t, idx = plan.gbank, plan.row, plan.write, plan.t, plan.outcomes.idx
    n = gbank.size
    b = timing.burst
    rank = gbank >> (geometry.banks.bit_length() - 1)
    bank = gbank & (geometry.banks - 1)
    auto = plan.outcomes.auto if plan.outcomes.auto is not None else np.zeros(n, dtype=bool)
    p_safe = plan.outcomes.p
    act_virtual = plan.act_virtual
    pre_t = act_virtual - timing.rp

    def recovery_of(index: np.ndarray) -> np.ndarray:
        read_recovery = timing.al + timing.rtp
        return write[index] * (timing.wl + b + timing.wr - read_recovery) + read_recovery

    refresh = _Refresh(timing, start)
    t_i = t[idx]
    k_col_i = refresh.count(t_i)
    col_real_i = refresh.real(t_i)
    k_pre = refresh.count(pre_t)
    explicit_pre = plan.outcomes.p_conflict & (k_pre <= refresh.count(t[p_safe]))
    # outcomes: conflicts are the activating requests with an explicit PRE; a refresh turned
    # the others (and the hits it interrupted) into misses
    lost_hits = _lost_hits(plan, refresh, geometry.ranks * geometry.banks)
    n_conflicts = int(np.count_nonzero(explicit_pre))
    n_hits = n - idx.size - lost_hits.size

    # activations: the model's own, a second one when a refresh fell between an early ACT and its
    # column command, and one for each hit turned into a miss by a refresh
    k_act = refresh.count(act_virtual)
    first_act_real = refresh.real(act_virtual)
    again = k_act < k_col_i
    act_req = np.concatenate((idx, idx[again], lost_hits))
    act_cycle = np.concatenate((first_act_real, col_real_i[again] - timing.rcd,
                                refresh.real(t[lost_hits]) - timing.rcd))
    pre_req = idx[explicit_pre]
    pre_cycle = refresh.real(pre_t[explicit_pre])

    last_real = int(refresh.real(t[-1:])[0]) + (np.where(write[-1], timing.wl, timing.rl) + b) if n else start
    shift = np.int64(1) << np.int64(42)
    act_bank = gbank[act_req]
    act_keys = act_bank * shift + act_cycle
    act_order = _by_bank(act_bank)  # nearly key order: the searches below run fast
    auto_cycle = np.zeros(0, dtype=np.int64)
    auto_req = np.flatnonzero(auto) if plan.outcomes.auto is not None else np.zeros(0, dtype=np.int64)
    if auto_req.size:
        auto_real = refresh.real(t[auto_req])
        sorted_acts = np.sort(act_keys)
        # the implicit precharge of RDA/WRA: after tRAS from the ACT that opened the row and after
        # the read (tRTP) or write recovery
        latest = np.searchsorted(sorted_acts, gbank[auto_req] * shift + auto_real, side="right") - 1
        opened = sorted_acts[np.maximum(latest, 0)] % shift
        auto_cycle = np.maximum(opened + timing.ras, auto_real + recovery_of(auto_req))
        # A row re-activated after a refresh restarts tRAS, which the refresh-free timing did not
        # see: where the implicit precharge would come after the bank's next ACT, the column
        # command is a plain RD/WR and an explicit PRE precedes that ACT instead.
        following = np.searchsorted(sorted_acts, gbank[auto_req] * shift + auto_real, side="right")
        padded_acts = np.append(sorted_acts, np.int64(-1))
        candidate = padded_acts[np.minimum(following, sorted_acts.size)]
        next_act = np.where(candidate // shift == gbank[auto_req], candidate % shift, np.iinfo(np.int64).max)
        late = auto_cycle > next_act - timing.rp
        if late.any():
            fixed = auto_req[late]
            auto = auto.copy()
            auto[fixed] = False
            pre_req = np.concatenate((pre_req, fixed))
            pre_cycle = np.concatenate((pre_cycle, np.maximum(next_act[late] - timing.rp, auto_real[late] + 1)))
            auto_req, auto_cycle, auto_real = auto_req[~late], auto_cycle[~late], auto_real[~late]
    end = int(max(last_real, int(act_cycle.max()) if act_cycle.size else 0,
                  int(auto_cycle.max()) + 1 if auto_cycle.size else 0))
    # an implicit precharge after a refresh's PREA closes nothing (the PREA did)
    next_ref = (auto_real // timing.refi + 1) * timing.refi if auto_req.size else auto_cycle
    preempted = (next_ref < auto_cycle) & (next_ref <= end)
    auto_req = auto_req[~preempted]
    auto_cycle = auto_cycle[~preempted]
    window_end = end + timing.rp if close_at_end else end
    first_ref = max(1, -(-start // timing.refi))
    ref_cycle = timing.refi * np.arange(first_ref, (window_end - 1) // timing.refi + 1, dtype=np.int64)

    # bank-open intervals: each ACT until the first of: the next precharge of its bank (explicit or
    # auto), the next refresh's PREA, the end
    close_key_bank = np.concatenate((gbank[pre_req], gbank[auto_req]))
    close_time = np.concatenate((pre_cycle, auto_cycle))
    close_keys = _sorted_keys(close_key_bank, close_key_bank * shift + close_time)
    pos = np.empty(act_keys.size, dtype=np.int64)  # searched in (nearly) key order, put back
    pos[act_order] = np.searchsorted(close_keys, act_keys[act_order], side="left")
    found = pos < close_keys.size
    padded = np.append(close_keys, np.int64(-1))
    candidate = padded[np.minimum(pos, close_keys.size)]
    found &= (candidate // shift) == act_bank
    next_close = np.where(found, candidate % shift, np.iinfo(np.int64).max)
    next_refresh = (act_cycle // timing.refi + 1) * timing.refi
    next_refresh = np.where(next_refresh <= end, next_refresh, np.iinfo(np.int64).max)
    close = np.minimum(np.minimum(next_close, next_refresh), end)
    by_prea = (next_refresh < next_close) & (next_refresh <= end)
    if close_at_end:  # precharge what is still open
        still_open = (next_close > end) & ~by_prea
        pre_req = np.concatenate((pre_req, act_req[still_open]))
        pre_cycle = np.concatenate((pre_cycle, np.full(int(still_open.sum()), end, dtype=np.int64)))
        end = window_end

    commands = Commands(
        act_cycle=act_cycle, act_rank=rank[act_req], act_bank=bank[act_req], act_row=row[act_req],
        pre_cycle=pre_cycle, pre_rank=rank[pre_req], pre_bank=bank[pre_req],
        col_cycle=refresh.real(t) if keep_commands else np.zeros(0, dtype=np.int64), col_rank=rank, col_bank=bank, col_row=row,
        col_column=column if column is not None else np.zeros(0, dtype=np.int64),
        col_write=write, col_auto=auto, ref_cycle=ref_cycle, end_cycle=end, refa_delay=timing.rp,
        start_cycle=start,
    )
    stats = stats_from_commands(geometry, timing, commands, rank[act_req], act_cycle, close, by_prea,
                                 rank[auto_req])
    writes = int(np.count_nonzero(write))
    return ControllerResult(
        stats=stats, requests=n, reads=n - writes, writes=writes,
        row_hits=n_hits, row_misses=n - n_hits - n_conflicts, row_conflicts=n_conflicts, cycles=end,
        commands=commands,
        geometry=geometry,
    )
