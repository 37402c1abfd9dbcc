"""Timing, row-buffer outcomes and refresh of a served request sequence (vectorised core).

Used by :func:`hdeem_watch.dram.controller.simulate`, which explains the model. All cycle figures
are int64. Every step is an array operation. Column commands are spaced by the column rules
(cumulative spacing ``G``); a request that needs an activation may add a lift (its bank is not
ready yet), and the lifts of the requests in between count towards the distance to the access it
waits for, so the lifts are a recurrence over the activating requests, solved by a few Jacobi
rounds on their cumulative sums (exact when no other lift lies in between, the common case).
"""

from __future__ import annotations

import numpy as np

from hdeem_watch.dram.controller import (
    Commands,
    ControllerResult,
    Timing,
    _column_gaps,
    stats_from_commands,
)
from hdeem_watch.dram.mapping import Geometry
from hdeem_watch.dram.scheduler import SchedulerConfig

_MAX_ROUNDS = 8


def _previous_same(key: np.ndarray, want_next: bool) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """For each element, the index of the previous (and next) element with the same key (-1 if none).

    Also returns the stable order by key.
    """
    n = key.size
    top = int(key.max()) if n else 0
    # narrow keys sort faster (radix); the stable order is the same
    small = key.astype(np.int8) if top < 128 else key.astype(np.int16) if top < 32767 else key
    order = np.argsort(small, kind="stable")
    sorted_key = small[order]
    first = np.flatnonzero(sorted_key[1:] != sorted_key[:-1]) + 1  # where each key's run starts
    earlier = order[:-1].copy()
    earlier[first - 1] = -1
    prev = np.empty(n, dtype=np.int64)
    if n:
        prev[order[0]] = -1
        prev[order[1:]] = earlier
    nxt = None
    if want_next:
        later = order[1:].copy()
        later[first - 1] = -1
        nxt = np.empty(n, dtype=np.int64)
        if n:
            nxt[order[-1]] = -1
            nxt[order[:-1]] = later
    return prev, nxt, order


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

    def count(self, virtual: np.ndarray) -> np.ndarray:
        period = self.refi - self.stall
        return np.maximum((virtual - self.first + period) // period, 0)

    def count_sorted(self, virtual: np.ndarray) -> np.ndarray:
        """:meth:`count` of a non-decreasing array: where each refresh falls, then a running count."""
        if virtual.size == 0:
            return np.zeros(0, dtype=np.int64)
        period = self.refi - self.stall
        refreshes = int(self.count(virtual[-1:])[0])
        thresholds = self.first + period * np.arange(refreshes, dtype=np.int64)
        marks = np.bincount(np.searchsorted(virtual, thresholds, side="left"), minlength=virtual.size + 1)
        return np.cumsum(marks[:-1])

    def real(self, virtual: np.ndarray) -> np.ndarray:
        return self.start + virtual + self.stall * self.count(virtual)


def run_timing(geometry: Geometry, timing: Timing, config: SchedulerConfig, policy: str, *,
               gbank: np.ndarray, row: np.ndarray,
               column: np.ndarray | None, write: np.ndarray, start: int = 0, close_at_end: bool = False) -> ControllerResult:
    """Time a request sequence already in service order and collect its commands and statistics.

    ``start`` is the cycle the sequence starts at (a chunk after earlier ones); ``close_at_end``
    precharges the banks left open and ends the window ``tRP`` later, so the next chunk starts
    with every bank precharged. ``column`` may be ``None`` when the commands are not kept (their
    ``col_column`` is then empty).
    """
    n = gbank.size
    # gbank = rank × banks + bank; all counts are powers of two: fields by shifts
    rank = gbank >> (geometry.banks.bit_length() - 1)
    bank = gbank & (geometry.banks - 1)
    bankgroup = gbank >> (geometry.banks_per_group.bit_length() - 1)  # unique over the ranks
    prev, nxt, by_bank = _previous_same(gbank, policy == "closed")
    has_prev = prev >= 0
    prev_safe = np.maximum(prev, 0)
    same_row = has_prev & (row[prev_safe] == row)
    queue = config.read_queue
    if nxt is not None:  # closed page
        nxt_safe = np.maximum(nxt, 0)
        auto = (nxt < 0) | (row[nxt_safe] != row) | (nxt - np.arange(n) > queue)
        hit = same_row & ~auto[prev_safe]
        conflict = has_prev & ~same_row & ~auto[prev_safe]
    else:
        auto = np.zeros(n, dtype=bool)
        hit = same_row
        conflict = has_prev & ~same_row
    need = ~hit
    b = timing.burst

    def recovery_of(index: np.ndarray) -> np.ndarray:
        read_recovery = timing.al + timing.rtp
        return write[index] * (timing.wl + b + timing.wr - read_recovery) + read_recovery

    gaps = _column_gaps(timing, rank, bankgroup, write, config.hidden_turnaround)
    cum = np.cumsum(gaps)
    idx = np.flatnonzero(need)
    m = idx.size
    p = prev[idx]
    p_has = p >= 0
    p_safe = np.maximum(p, 0)
    p_conflict = conflict[idx]
    # q: the activation that opened p's row = the previous activating request of the same bank
    # (no request of that bank lies between p and i); 0 where there is none (no p either)
    need_by_bank = by_bank[need[by_bank]]  # activating requests, stably sorted by bank
    q = np.zeros(m, dtype=np.int64)
    if m > 1:
        same_bank = gbank[need_by_bank[1:]] == gbank[need_by_bank[:-1]]
        need_rank = np.cumsum(need, dtype=np.int32)  # activating requests up to and including i
        later = need_by_bank[1:][same_bank]
        q[need_rank[later] - 1] = need_by_bank[:-1][same_bank]
    else:
        need_rank = np.cumsum(need, dtype=np.int32)
    # Each request that needs an activation may lift the column sequence: it must wait for its
    # bank (t_p + recovery + tRP + tRCD after the previous access p, and tRAS + tRP after the
    # ACT that opened p's row). Lifts of requests in between count towards that distance, so the
    # lifts are a recurrence over the activating requests; a few Jacobi rounds solve it.
    recovery_p = recovery_of(p_safe)
    cum_i = cum[idx]
    wait_p = recovery_p + (timing.rp + timing.rcd - config.hidden_bank) - (cum_i - cum[p_safe])
    wait_q = (timing.ras + timing.rp) - (cum_i - cum[q])
    rank_p = need_rank[p_safe]  # activating requests up to and including p
    rank_q = need_rank[q]
    rank_i = np.arange(m, dtype=np.int32)  # activating requests before i
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
    del rank_i
    lifts = np.zeros(n, dtype=np.int64)
    lifts[idx] = lam
    t = np.cumsum(lifts)
    t += cum
    t += timing.rcd
    # activation times: as early as the bank and the queue allow, at the latest tRCD before the column
    enter = t[np.maximum(idx - queue, 0)]
    enter *= idx >= queue
    ready = np.maximum(t[q] + (timing.ras - timing.rcd), t[p_safe] + recovery_p)
    ready += timing.rp
    ready *= p_has
    t_i = t[idx]
    act_virtual = np.minimum(np.maximum(ready, enter), t_i - timing.rcd)
    pre_t = act_virtual - timing.rp

    refresh = _Refresh(timing, start)
    k_col = refresh.count_sorted(t)  # t never decreases (gaps and lifts are >= 0)
    col_real = refresh.start + t + refresh.stall * k_col
    # refresh closes the row: a hit or conflict whose previous same-bank access precedes a refresh
    refreshed = has_prev & (k_col > k_col[prev_safe])
    k_pre = refresh.count(pre_t)
    explicit_pre = p_conflict & (k_pre <= k_col[p_safe])
    # outcomes: conflicts are the activating requests with an explicit PRE; a refresh turned
    # the others (and the hits it interrupted) into misses
    lost_hits = np.flatnonzero(hit & refreshed)
    n_conflicts = int(np.count_nonzero(explicit_pre))
    n_hits = int(np.count_nonzero(hit)) - lost_hits.size

    # activations: the model's own, a second one when a refresh fell between an early ACT and its
    # column command, and one for each hit turned into a miss by a refresh
    k_act = refresh.count(act_virtual)
    first_act_real = refresh.real(act_virtual)
    k_col_i = k_col[idx]
    again = k_act < k_col_i
    act_req = np.concatenate((idx, idx[again], lost_hits))
    act_cycle = np.concatenate((first_act_real, col_real[idx[again]] - timing.rcd, col_real[lost_hits] - timing.rcd))
    pre_req = idx[explicit_pre]
    pre_cycle = refresh.real(pre_t[explicit_pre])

    last_real = int(col_real[-1]) + (np.where(write[-1], timing.wl, timing.rl) + b) if n else start
    shift = np.int64(1) << np.int64(42)
    act_bank = gbank[act_req]
    act_keys = act_bank * shift + act_cycle
    act_order = _by_bank(act_bank)  # nearly key order: the searches below run fast
    auto_cycle = np.zeros(0, dtype=np.int64)
    auto_req = np.flatnonzero(auto)
    if auto_req.size:
        sorted_acts = np.sort(act_keys)
        # the implicit precharge of RDA/WRA: after tRAS from the ACT that opened the row and after
        # the read (tRTP) or write recovery
        latest = np.searchsorted(sorted_acts, gbank[auto_req] * shift + col_real[auto_req], side="right") - 1
        opened = sorted_acts[np.maximum(latest, 0)] % shift
        auto_cycle = np.maximum(opened + timing.ras, col_real[auto_req] + recovery_of(auto_req))
        # A row re-activated after a refresh restarts tRAS, which the refresh-free timing did not
        # see: where the implicit precharge would come after the bank's next ACT, the column
        # command is a plain RD/WR and an explicit PRE precedes that ACT instead.
        following = np.searchsorted(sorted_acts, gbank[auto_req] * shift + col_real[auto_req], side="right")
        padded_acts = np.append(sorted_acts, np.int64(-1))
        candidate = padded_acts[np.minimum(following, sorted_acts.size)]
        next_act = np.where(candidate // shift == gbank[auto_req], candidate % shift, np.iinfo(np.int64).max)
        late = auto_cycle > next_act - timing.rp
        if late.any():
            fixed = auto_req[late]
            auto = auto.copy()
            auto[fixed] = False
            pre_req = np.concatenate((pre_req, fixed))
            pre_cycle = np.concatenate((pre_cycle, np.maximum(next_act[late] - timing.rp, col_real[fixed] + 1)))
            auto_req, auto_cycle = auto_req[~late], auto_cycle[~late]
    end = int(max(last_real, int(act_cycle.max()) if act_cycle.size else 0,
                  int(auto_cycle.max()) + 1 if auto_cycle.size else 0))
    # an implicit precharge after a refresh's PREA closes nothing (the PREA did)
    next_ref = (col_real[auto_req] // timing.refi + 1) * timing.refi
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
        col_cycle=col_real, col_rank=rank, col_bank=bank, col_row=row,
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
