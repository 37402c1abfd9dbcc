"""Refresh, activation rules, commands and statistics of a served request sequence (vectorised core).

Used by :func:`hdeem_watch.dram.controller.simulate`, which explains the model. The refresh-free
times come from :mod:`hdeem_watch.dram.timing_plan` (whose lifts already keep the just-in-time
activations tRRD_S/L and tFAW apart); :func:`run_timing` inserts the refresh stalls in closed form
and collects the activations: the model's own, a second one where a refresh closed a row opened
ahead of its column command, one for each hit a refresh turned into a miss. The model's own ACTs
are spaced by tRRD_S/L and tFAW in the order they are ready (:mod:`hdeem_watch.dram.act_spacing`,
first come first served, with the chunk before's last ACTs); where one then comes later than tRCD
before its column command, the plan is asked for a later column and the round repeats (at most
:data:`MAX_SPACING_ROUNDS`). The re-activations after a refresh are not spaced. Then the precharges
(explicit, RDA/WRA's implicit ones), the bank-open intervals, the commands and their statistics.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from hdeem_watch.dram.act_spacing import (
    ActRules,
    RecentActs,
    RefreshWindows,
    recent_activations,
    space_activations,
)
from hdeem_watch.dram.command_set import (
    Commands,
    ControllerResult,
    Timing,
    stats_from_commands,
)
from hdeem_watch.dram.mapping import Geometry
from hdeem_watch.dram.row_outcomes import Outcomes
from hdeem_watch.dram.scheduler import SchedulerConfig
from hdeem_watch.dram.timing_plan import TimingPlan, _by_bank, plan_timing

#: Rounds of spacing the activations and re-planning the columns before the result stands as it is.
MAX_SPACING_ROUNDS = 4
#: Late activations fewer requests apart than this delay each other (:func:`_later_columns`).
_REACH = 64
_SHIFT = np.int64(1) << np.int64(42)
_NEVER = np.iinfo(np.int64).max


def _sorted_keys(bank: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """``np.sort(keys)`` for ``keys = bank × 2^42 + cycle`` whose events of one bank are mostly in
    time order already: sorted by bank, checked, fully sorted only if that was not enough."""
    ordered = keys[_by_bank(bank)]
    if ordered.size > 1 and bool((ordered[1:] < ordered[:-1]).any()):
        ordered = np.sort(keys)
    return ordered


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
        #: index ``k`` of the first refresh (at real cycle ``k × tREFI``)
        self.first_index = max(1, -(-start // self.refi))

    def count(self, virtual: np.ndarray) -> np.ndarray:
        return np.maximum((virtual - self.first + self.period) // self.period, 0)

    def thresholds(self, last: int) -> np.ndarray:
        """Virtual times of the refreshes up to ``last``."""
        refreshes = int(self.count(np.array([last], dtype=np.int64))[0])
        return self.first + self.period * np.arange(refreshes, dtype=np.int64)

    def real(self, virtual: np.ndarray) -> np.ndarray:
        return self.start + virtual + self.stall * self.count(virtual)


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


@dataclass(frozen=True)
class _Activations:
    """The activations and explicit precharges of a timed sequence (real cycles).

    Attributes:
        req, cycle: request and cycle of each ACT.
        early: an ACT a refresh closed before its column command (the request activates again).
        pre_req, pre_cycle: explicit precharges.
        lost_hits: hits a refresh turned into misses.
        conflicts: requests that found another row open.
    """

    req: np.ndarray
    cycle: np.ndarray
    early: np.ndarray
    pre_req: np.ndarray
    pre_cycle: np.ndarray
    lost_hits: np.ndarray
    conflicts: int


def _activations(plan: TimingPlan, refresh: _Refresh, timing: Timing, banks_total: int) -> _Activations:
    """The model's activations, a second one when a refresh fell between an early ACT and its
    column command, and one for each hit turned into a miss by a refresh; and the explicit PREs."""
    t, idx = plan.t, plan.outcomes.idx
    act_virtual = plan.act_virtual
    pre_t = act_virtual - timing.rp
    t_i = t[idx]
    col_real_i = refresh.real(t_i)
    # outcomes: conflicts are the activating requests with an explicit PRE; a refresh turned
    # the others (and the hits it interrupted) into misses
    explicit_pre = plan.outcomes.p_conflict & (refresh.count(pre_t) <= refresh.count(t[plan.outcomes.p]))
    lost_hits = _lost_hits(plan, refresh, banks_total)
    again = refresh.count(act_virtual) < refresh.count(t_i)
    return _Activations(
        req=np.concatenate((idx, idx[again], lost_hits)),
        cycle=np.concatenate((refresh.real(act_virtual), col_real_i[again] - timing.rcd,
                              refresh.real(t[lost_hits]) - timing.rcd)),
        early=np.concatenate((again, np.zeros(int(again.sum()) + lost_hits.size, dtype=bool))),
        pre_req=idx[explicit_pre], pre_cycle=refresh.real(pre_t[explicit_pre]), lost_hits=lost_hits,
        conflicts=int(np.count_nonzero(explicit_pre)))


def _spaced(geometry: Geometry, timing: Timing, config: SchedulerConfig, policy: str, plan: TimingPlan,
            refresh: _Refresh, acts: _Activations, prior: RecentActs | None) -> tuple[TimingPlan, _Activations]:
    """The plan and activations with the model's own ACTs spaced by tRRD_S/L and tFAW.

    An ACT the rules delay past ``column − tRCD`` asks the plan for a later column (``floors`` of an
    activating request); the plan is re-timed and the activations spaced again until none is late or
    :data:`MAX_SPACING_ROUNDS` have passed (then the last spacing stands: the rules hold, tRCD may
    fall short by a few cycles). An early ACT the rules push past the refresh before its column is
    dropped: the second activation after the refresh serves.
    """
    rules = ActRules(timing.rrd_s, timing.rrd_l, timing.faw)
    windows = RefreshWindows(timing.refi, max(0, refresh.stall - timing.rcd), refresh.first_index)
    rank = plan.gbank >> (geometry.banks.bit_length() - 1)
    group = plan.gbank >> _group_shift(geometry)
    idx = plan.outcomes.idx
    floors: np.ndarray | None = None
    extra: np.ndarray | None = None
    own = idx.size  # the model's own ACTs come first; the refresh's re-activations stay where they are
    for round_ in range(MAX_SPACING_ROUNDS + 1):
        col_real = refresh.real(plan.t[acts.req])
        spaced = acts.cycle.copy()
        spaced[:own] = _space(acts.cycle[:own], acts.req[:own], rank, group, rules, windows, prior)
        keep = ~(acts.early & (spaced // timing.refi >= col_real // timing.refi))
        late = np.where(keep, spaced + timing.rcd - col_real, 0)
        if not (late > 0).any() or round_ == MAX_SPACING_ROUNDS:
            break
        floors, extra = _later_columns(plan, acts.req, late, floors, extra, _REACH)
        plan = plan_timing(geometry, timing, config, policy, gbank=plan.gbank, row=plan.row, write=plan.write,
                           outcomes=plan.outcomes, floors=floors, extra=extra)
        acts = _activations(plan, refresh, timing, geometry.ranks * geometry.banks)
    return plan, replace(acts, req=acts.req[keep], cycle=spaced[keep], early=acts.early[keep])


def _later_columns(plan: TimingPlan, act_req: np.ndarray, late: np.ndarray, floors: np.ndarray | None,
                   extra: np.ndarray | None, reach: int) -> tuple[np.ndarray, np.ndarray | None]:
    """The plan's demands for the next round: every column from a late ACT's on moves later (the
    sequence after it keeps its shape): a floor on each activating request's column, and extra
    spacing before a late hit (which has no lift of its own).

    Late ACTs less than ``reach`` requests apart delay each other (one moves by the largest
    lateness of its group so far); groups further apart are independent, so their delays add up.
    """
    n, idx = plan.t.size, plan.outcomes.idx
    late_req = np.zeros(n, dtype=np.int64)
    np.maximum.at(late_req, act_req, late)
    where = np.flatnonzero(late_req > 0)
    values = late_req[where]
    group_start = np.ones(where.size, dtype=bool)
    group_start[1:] = np.diff(where) > reach
    group = np.cumsum(group_start) - 1
    group_max = np.maximum.reduceat(values, np.flatnonzero(group_start)) if where.size else values
    before = np.concatenate(([0], np.cumsum(group_max)))[group]
    within = np.maximum.accumulate(values + (group << 40)) - (group << 40)
    shift = np.zeros(n, dtype=np.int64)
    shift[where] = before + within
    np.maximum.accumulate(shift, out=shift)
    need = plan.t[idx] + shift[idx]
    floors = need if floors is None else np.maximum(floors, need)
    rise = np.diff(shift, prepend=0)
    rise[idx] = 0
    if rise.any():
        extra = rise if extra is None else extra + rise
    return floors, extra


def _space(cycle: np.ndarray, req: np.ndarray, rank: np.ndarray, group: np.ndarray, rules: ActRules,
           windows: RefreshWindows, prior: RecentActs | None) -> np.ndarray:
    """:func:`space_activations` of the ACTs of requests ``req`` (earliest ``cycle``) after the
    ``prior`` chunk's last ACTs."""
    if prior is None or prior.cycle.size == 0:
        return space_activations(cycle, rank[req], group[req], rules, windows)
    spaced = space_activations(np.concatenate((prior.cycle, cycle)), np.concatenate((prior.rank, rank[req])),
                               np.concatenate((prior.group, group[req])), rules, windows)
    return spaced[prior.cycle.size:]


@dataclass(frozen=True)
class _Closes:
    """How the banks get closed: explicit precharges, RDA/WRA's implicit ones (with their requests)."""

    auto: np.ndarray
    auto_req: np.ndarray
    auto_cycle: np.ndarray
    pre_req: np.ndarray
    pre_cycle: np.ndarray
    end: int


def _implicit_precharges(plan: TimingPlan, refresh: _Refresh, timing: Timing, acts: _Activations,
                         last_real: int) -> _Closes:
    """RDA/WRA's implicit precharges: after tRAS from the ACT that opened the row and after the
    read (tRTP) or write recovery. A row re-activated after a refresh restarts tRAS, which the
    refresh-free timing did not see: where the implicit precharge would come after the bank's next
    ACT, the column command is a plain RD/WR and an explicit PRE precedes that ACT instead. An
    implicit precharge after a refresh's PREA closes nothing (the PREA did)."""
    gbank, t, write = plan.gbank, plan.t, plan.write
    n = gbank.size
    auto = plan.outcomes.auto if plan.outcomes.auto is not None else np.zeros(n, dtype=bool)
    auto_req = np.flatnonzero(auto) if plan.outcomes.auto is not None else np.zeros(0, dtype=np.int64)
    auto_cycle = auto_real = np.zeros(0, dtype=np.int64)
    pre_req, pre_cycle = acts.pre_req, acts.pre_cycle
    if auto_req.size:
        auto_real = refresh.real(t[auto_req])
        sorted_acts = np.sort(gbank[acts.req] * _SHIFT + acts.cycle)
        keys = gbank[auto_req] * _SHIFT + auto_real
        following = np.searchsorted(sorted_acts, keys, side="right")
        opened = sorted_acts[np.maximum(following - 1, 0)] % _SHIFT
        read_recovery = timing.al + timing.rtp
        recovery = write[auto_req] * (timing.wl + timing.burst + timing.wr - read_recovery) + read_recovery
        auto_cycle = np.maximum(opened + timing.ras, auto_real + recovery)
        candidate = np.append(sorted_acts, np.int64(-1))[np.minimum(following, sorted_acts.size)]
        next_act = np.where(candidate // _SHIFT == gbank[auto_req], candidate % _SHIFT, _NEVER)
        late = auto_cycle > next_act - timing.rp
        if late.any():
            fixed = auto_req[late]
            auto = auto.copy()
            auto[fixed] = False
            pre_req = np.concatenate((pre_req, fixed))
            pre_cycle = np.concatenate((pre_cycle, np.maximum(next_act[late] - timing.rp, auto_real[late] + 1)))
            auto_req, auto_cycle, auto_real = auto_req[~late], auto_cycle[~late], auto_real[~late]
    end = int(max(last_real, int(acts.cycle.max()) if acts.cycle.size else 0,
                  int(auto_cycle.max()) + 1 if auto_cycle.size else 0))
    next_ref = (auto_real // timing.refi + 1) * timing.refi
    preempted = (next_ref < auto_cycle) & (next_ref <= end)
    return _Closes(auto=auto, auto_req=auto_req[~preempted], auto_cycle=auto_cycle[~preempted],
                   pre_req=pre_req, pre_cycle=pre_cycle, end=end)


@dataclass(frozen=True)
class _OpenIntervals:
    """Each ACT's bank-open interval: ``close`` (next precharge of its bank, the next refresh's
    PREA, or the end), whether the PREA closed it, and what ``close_at_end`` added."""

    close: np.ndarray
    by_prea: np.ndarray
    pre_req: np.ndarray
    pre_cycle: np.ndarray
    end: int


def _open_intervals(gbank: np.ndarray, timing: Timing, acts: _Activations, closes: _Closes,
                    close_at_end: bool) -> _OpenIntervals:
    """Bank-open intervals: each ACT until the first of the next precharge of its bank (explicit or
    auto), the next refresh's PREA, the end; with ``close_at_end``, what is still open is precharged
    at the end and the window ends tRP later."""
    end = closes.end
    act_bank = gbank[acts.req]
    act_keys = act_bank * _SHIFT + acts.cycle
    act_order = _by_bank(act_bank)  # nearly key order: the searches below run fast
    close_key_bank = np.concatenate((gbank[closes.pre_req], gbank[closes.auto_req]))
    close_time = np.concatenate((closes.pre_cycle, closes.auto_cycle))
    close_keys = _sorted_keys(close_key_bank, close_key_bank * _SHIFT + close_time)
    pos = np.empty(act_keys.size, dtype=np.int64)  # searched in (nearly) key order, put back
    pos[act_order] = np.searchsorted(close_keys, act_keys[act_order], side="left")
    found = pos < close_keys.size
    candidate = np.append(close_keys, np.int64(-1))[np.minimum(pos, close_keys.size)]
    found &= (candidate // _SHIFT) == act_bank
    next_close = np.where(found, candidate % _SHIFT, _NEVER)
    next_refresh = (acts.cycle // timing.refi + 1) * timing.refi
    next_refresh = np.where(next_refresh <= end, next_refresh, _NEVER)
    close = np.minimum(np.minimum(next_close, next_refresh), end)
    by_prea = (next_refresh < next_close) & (next_refresh <= end)
    pre_req, pre_cycle = closes.pre_req, closes.pre_cycle
    if close_at_end:  # precharge what is still open
        still_open = (next_close > end) & ~by_prea
        pre_req = np.concatenate((pre_req, acts.req[still_open]))
        pre_cycle = np.concatenate((pre_cycle, np.full(int(still_open.sum()), end, dtype=np.int64)))
        end += timing.rp
    return _OpenIntervals(close=close, by_prea=by_prea, pre_req=pre_req, pre_cycle=pre_cycle, end=end)


def run_timing(geometry: Geometry, timing: Timing, config: SchedulerConfig, policy: str, *,
               gbank: np.ndarray, row: np.ndarray,
               column: np.ndarray | None, write: np.ndarray, start: int = 0, close_at_end: bool = False,
               plan: TimingPlan | None = None, outcomes: Outcomes | None = None,
               keep_commands: bool = True, prior: RecentActs | None = None) -> ControllerResult:
    """Time a request sequence already in service order and collect its commands and statistics.

    ``start`` is the cycle the sequence starts at (a chunk after earlier ones); ``close_at_end``
    precharges the banks left open and ends the window ``tRP`` later, so the next chunk starts
    with every bank precharged. ``column`` may be ``None`` when the commands are not kept (their
    ``col_column`` is then empty). ``plan``: :func:`plan_timing` of the sequence, or ``outcomes``: its
    :func:`hdeem_watch.dram.row_outcomes.row_outcomes`, if already computed. ``keep_commands=False``
    leaves ``col_cycle`` empty (the statistics do not need it). ``prior``: the last activations of the
    chunk before (:func:`~hdeem_watch.dram.act_spacing.recent_activations`), which tRRD and tFAW still see.
    """
    if plan is None:
        plan = plan_timing(geometry, timing, config, policy, gbank=gbank, row=row, write=write, outcomes=outcomes)
    refresh = _Refresh(timing, start)
    acts = _activations(plan, refresh, timing, geometry.ranks * geometry.banks)
    if ActRules(timing.rrd_s, timing.rrd_l, timing.faw).binding:
        plan, acts = _spaced(geometry, timing, config, policy, plan, refresh, acts, prior)
    gbank, row, write, t = plan.gbank, plan.row, plan.write, plan.t
    n = gbank.size
    last_real = int(refresh.real(t[-1:])[0]) + int(np.where(write[-1], timing.wl, timing.rl)) + timing.burst if n else start
    closes = _implicit_precharges(plan, refresh, timing, acts, last_real)
    window_end = closes.end + timing.rp if close_at_end else closes.end
    first_ref = max(1, -(-start // timing.refi))
    ref_cycle = timing.refi * np.arange(first_ref, (window_end - 1) // timing.refi + 1, dtype=np.int64)
    intervals = _open_intervals(gbank, timing, acts, closes, close_at_end)
    rank = gbank >> (geometry.banks.bit_length() - 1)
    bank = gbank & (geometry.banks - 1)
    commands = Commands(
        act_cycle=acts.cycle, act_rank=rank[acts.req], act_bank=bank[acts.req], act_row=row[acts.req],
        pre_cycle=intervals.pre_cycle, pre_rank=rank[intervals.pre_req], pre_bank=bank[intervals.pre_req],
        col_cycle=refresh.real(t) if keep_commands else np.zeros(0, dtype=np.int64), col_rank=rank, col_bank=bank,
        col_row=row, col_column=column if column is not None else np.zeros(0, dtype=np.int64),
        col_write=write, col_auto=closes.auto, ref_cycle=ref_cycle, end_cycle=intervals.end,
        refa_delay=timing.rp, start_cycle=start,
    )
    stats = stats_from_commands(geometry, timing, commands, rank[acts.req], acts.cycle, intervals.close,
                                intervals.by_prea, rank[closes.auto_req])
    writes = int(np.count_nonzero(write))
    n_hits = n - plan.outcomes.idx.size - acts.lost_hits.size
    return ControllerResult(
        stats=stats, requests=n, reads=n - writes, writes=writes, row_hits=n_hits,
        row_misses=n - n_hits - acts.conflicts, row_conflicts=acts.conflicts, cycles=intervals.end,
        commands=commands, geometry=geometry,
        recent_acts=recent_activations(acts.cycle, rank[acts.req], (gbank >> _group_shift(geometry))[acts.req]),
    )


def _group_shift(geometry: Geometry) -> int:
    """``gbank >> _group_shift`` numbers the bank groups uniquely over the ranks."""
    return geometry.banks_per_group.bit_length() - 1
