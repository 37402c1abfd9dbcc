"""The refresh-free timing of a served request sequence (vectorised core).

Used by :mod:`hdeem_watch.dram.timing_model`, which adds refresh, the activation rules, commands
and statistics; the row-buffer outcomes come from :mod:`hdeem_watch.dram.row_outcomes`. All cycle
figures are int64 and every step is an array operation. Column commands are spaced by the column
rules (cumulative spacing ``G``); a request that needs an activation may add a lift (its bank is not
ready yet), and the lifts of the requests in between count towards the distance to the access it
waits for, so the lifts are a recurrence over the activating requests, solved by a few Jacobi
rounds on their cumulative sums (exact when no other lift lies in between, the common case), or
exactly by cumulative maxima when the activation rules demand a later column (``floors``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hdeem_watch.dram.command_set import Timing
from hdeem_watch.dram.mapping import Geometry
from hdeem_watch.dram.row_outcomes import Outcomes, row_outcomes
from hdeem_watch.dram.scheduler import SchedulerConfig

#: Jacobi rounds of the lifts.
_MAX_ROUNDS = 8
#: Rounds of cumulative maxima of the exact lifts before the plain loop.
_MAX_EXACT_ROUNDS = 32


def _by_bank(bank: np.ndarray) -> np.ndarray:
    """Stable order by bank (a radix sort on a narrow copy of the small bank index)."""
    small = bank.astype(np.int8) if bank.size and int(bank.max()) < 128 else bank
    return np.argsort(small, kind="stable")


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
                outcomes: Outcomes | None = None, floors: np.ndarray | None = None,
                extra: np.ndarray | None = None) -> TimingPlan:
    """Row-buffer outcomes and refresh-free times of a sequence in service order (see the module doc).

    ``outcomes``: :func:`hdeem_watch.dram.row_outcomes.row_outcomes` of the sequence, if already
    computed. ``floors`` (one per activating request, ``outcomes.idx``): the earliest virtual cycle of
    its column command (the activation rules' demand, :mod:`hdeem_watch.dram.timing_model`);
    ``extra`` (one per request): cycles added to the spacing before it. With either, the lifts are
    solved exactly (:func:`_exact_lifts`), else by the Jacobi rounds of :func:`_jacobi_lifts`.
    """
    n = gbank.size
    if outcomes is None:
        outcomes = row_outcomes(geometry, config, policy, gbank=gbank, row=row)
    idx, p_safe, p_has, q = outcomes.idx, outcomes.p, outcomes.p_has, outcomes.q
    b = timing.burst

    def recovery_of(index: np.ndarray) -> np.ndarray:
        read_recovery = timing.al + timing.rtp
        return write[index] * (timing.wl + b + timing.wr - read_recovery) + read_recovery

    rank = gbank >> (geometry.banks.bit_length() - 1)
    bankgroup = gbank >> (geometry.banks_per_group.bit_length() - 1)  # unique over the ranks
    cum = _column_gaps(timing, rank, bankgroup, write, config.hidden_turnaround)
    del rank, bankgroup
    if extra is not None:
        cum += extra
    np.cumsum(cum, out=cum)
    # Each request that needs an activation may lift the column sequence: it must wait for its
    # bank (t_p + recovery + tRP + tRCD after the previous access p, and tRAS + tRP after the
    # ACT that opened p's row). Lifts of requests in between count towards that distance, so the
    # lifts are a recurrence over the activating requests.
    recovery_p = recovery_of(p_safe)
    cum_i = cum[idx]
    wait_p = recovery_p + (timing.rp + timing.rcd - config.hidden_bank) - (cum_i - cum[p_safe])
    wait_q = (timing.ras + timing.rp) - (cum_i - cum[q])
    has = outcomes.p_has.astype(bool)
    bounds = [(outcomes.rank_p, wait_p, has), (outcomes.rank_q, wait_q, has)]
    if timing.rrd_s > 0 or timing.rrd_l > 0 or timing.faw > 0:
        bounds += _activation_bounds(geometry, timing, gbank[idx], cum_i)
    if floors is None and extra is None:
        lifted, settled = _jacobi_lifts(bounds, idx.size)
        if not settled and len(bounds) > 2:  # with the activation rules the answer must be exact
            lifted = _lifts_one_by_one(bounds, np.zeros(idx.size, dtype=np.int64))
    else:
        floor = floors - (cum_i + timing.rcd) if floors is not None else np.zeros(idx.size, dtype=np.int64)
        lifted = _exact_lifts(bounds, floor)
    # column times: the spacing plus the lifts so far (request 0 always activates: idx[0] = 0)
    t = cum
    if idx.size:
        t += np.repeat(lifted, np.diff(idx, append=n))
    t += timing.rcd
    # activation times: as early as the bank and the queue allow, at the latest tRCD before the column
    queue = config.read_queue
    enter = t[np.maximum(idx - queue, 0)]
    enter *= idx >= queue
    ready = np.maximum(t[q] + (timing.ras - timing.rcd), t[p_safe] + recovery_p)
    ready += timing.rp
    ready *= p_has
    act_virtual = np.minimum(np.maximum(ready, enter), t[idx] - timing.rcd)
    return TimingPlan(gbank=gbank, row=row, write=write, outcomes=outcomes, t=t, act_virtual=act_virtual)


def _jacobi_lifts(bounds: list[Bound], m: int) -> tuple[np.ndarray, bool]:
    """Cumulative lift up to each of the ``m`` activating requests, and whether it settled: a few
    Jacobi rounds on the lifts (each lift the largest shortfall of its bounds, given the lifts in
    between; exact when no other lift lies in between, the common case). A settled answer is the
    recurrence's unique solution (:func:`_exact_lifts`)."""
    lam = np.zeros(m, dtype=np.int64)
    for _ref, offset, mask in bounds:
        np.maximum(lam, np.where(mask, offset, 0), out=lam)
    settled = False
    for _ in range(_MAX_ROUNDS):
        total = np.zeros(m + 1, dtype=np.int64)
        np.cumsum(lam, out=total[1:])
        total_i = total[:-1]  # = total[rank_i]
        new_lam = np.zeros(m, dtype=np.int64)
        for ref, offset, mask in bounds:
            np.maximum(new_lam, np.where(mask, offset - (total_i - total[ref]), 0), out=new_lam)
        if np.array_equal(new_lam, lam):
            settled = True
            break
        lam = new_lam
    np.cumsum(lam, out=lam)
    return lam, settled


#: A lower bound on the cumulative lift of each activating request: ``L_j >= L[ref_j] + offset_j``
#: where ``mask_j`` (``L[0] = 0``; ``ref_j <= j``: the lift up to an earlier request).
Bound = tuple[np.ndarray, np.ndarray, np.ndarray]


def _activation_bounds(geometry: Geometry, timing: Timing, gbank: np.ndarray, cum_i: np.ndarray) -> list[Bound]:
    """tRRD_S, tRRD_L and tFAW between the activating requests' just-in-time ACTs (tRCD before
    their column commands, in request order): the column of each activating request at least the
    rule after that of the previous one of its rank, of its bank group, and of the fourth before
    it in its rank."""
    rank = gbank >> (geometry.banks.bit_length() - 1)
    group = gbank >> (geometry.banks_per_group.bit_length() - 1)
    bounds = []
    for key, back, gap in ((rank, 1, timing.rrd_s), (group, 1, timing.rrd_l), (rank, 4, timing.faw)):
        if gap <= 0:
            continue
        order = np.argsort(key, kind="stable")
        earlier = np.full(key.size, -1, dtype=np.int64)
        if key.size > back:
            same = key[order][back:] == key[order][:-back]
            earlier[order[back:][same]] = order[:-back][same]
        mask = earlier >= 0
        bounds.append((earlier + 1, gap - (cum_i - cum_i[np.maximum(earlier, 0)]), mask))
    return bounds


def _exact_lifts(bounds: list[Bound], floor: np.ndarray) -> np.ndarray:
    """Cumulative lift ``L`` up to each activating request: the unique solution of ``L_j =
    max(L_{j-1}, floor_j, 0, L[ref_j] + offset_j for each bound)`` (``ref_j <= j``: a forward
    recurrence), by rounds of cumulative maxima from 0 (monotone), finished one request at a time
    if :data:`_MAX_EXACT_ROUNDS` do not settle it."""
    m = floor.size
    lifts = np.zeros(m + 1, dtype=np.int64)
    for _ in range(_MAX_EXACT_ROUNDS):
        demand = np.maximum(floor, 0)
        for ref, offset, mask in bounds:
            np.maximum(demand, np.where(mask, offset + lifts[ref], 0), out=demand)
        settled = np.array_equal(lifts[1:], np.maximum.accumulate(demand))
        lifts[1:] = np.maximum.accumulate(demand)
        if settled:
            return lifts[1:]
    return _lifts_one_by_one(bounds, floor)


def _lifts_one_by_one(bounds: list[Bound], floor: np.ndarray) -> np.ndarray:
    """:func:`_exact_lifts`' recurrence, one activating request at a time."""
    rows = [(ref.tolist(), offset.tolist(), mask.tolist()) for ref, offset, mask in bounds]
    out = [0] * (floor.size + 1)
    for j, value in enumerate(floor.tolist()):
        value = max(value, out[j], 0)
        for ref, offset, mask in rows:
            if mask[j]:
                value = max(value, offset[j] + out[ref[j]])
        out[j + 1] = value
    return np.array(out[1:], dtype=np.int64)
