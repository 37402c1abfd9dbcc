"""Row-buffer outcome of every request of a served sequence, from one stable order by bank.

Used by :mod:`hdeem_watch.dram.timing_model` (and computed ahead, in the preparing thread, by
:func:`hdeem_watch.dram.controller.simulate`). In the stable order by bank each request's
predecessor in its bank is its neighbour, so hits (same row as the bank's previous request),
conflicts (another row open) and misses (bank precharged) are neighbour comparisons. A closed
page closes a row (RDA/WRA) unless the bank's next request hits it within the queue's reach.
Independent of the time the sequence starts (refresh comes later).

Example:
    >>> import numpy as np
    >>> from hdeem_watch.dram.mapping import Geometry
    >>> from hdeem_watch.dram.scheduler import SchedulerConfig
    >>> geometry = Geometry(channels=1, ranks=1, bankgroups=4, banks_per_group=4, rows=65536,
    ...                     columns=1024, burst_length=8, transaction_bytes=64)
    >>> out = row_outcomes(geometry, SchedulerConfig(), "open", gbank=np.array([0, 1, 0, 0]),
    ...                    row=np.array([5, 5, 5, 6]))
    >>> out.idx.tolist(), out.p.tolist(), out.p_conflict.tolist()
    ([0, 1, 3], [0, 0, 2], [False, False, True])
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hdeem_watch.dram.mapping import Geometry
from hdeem_watch.dram.scheduler import SchedulerConfig


@dataclass(frozen=True)
class Outcomes:
    """Outcomes of a request sequence (service order).

    Attributes:
        auto: RDA/WRA flag of each request (closed page), ``None`` for the open page.
        idx: the requests that need an activation, ascending (request 0 always does).
        p, p_has: the previous request of each one's bank (0 where there is none), and whether
            there is one.
        q: the activation that opened ``p``'s row (the bank's previous activating request; 0 where none).
        p_conflict: ``p`` left another row open (a precharge is needed).
        rank_p, rank_q: activating requests up to and including ``p`` and ``q``.
        by_bank: the stable order by bank; ``bank_sorted``, ``hit_sorted``: banks and hits in it.
    """

    auto: np.ndarray | None
    idx: np.ndarray
    p: np.ndarray
    p_has: np.ndarray
    q: np.ndarray
    p_conflict: np.ndarray
    rank_p: np.ndarray
    rank_q: np.ndarray
    by_bank: np.ndarray
    bank_sorted: np.ndarray
    hit_sorted: np.ndarray


def row_outcomes(geometry: Geometry, config: SchedulerConfig, policy: str, *, gbank: np.ndarray,
                 row: np.ndarray) -> Outcomes:
    """Hits, misses and conflicts of a sequence in service order (global bank index ``gbank``)."""
    n = gbank.size
    banks_total = geometry.ranks * geometry.banks
    # one stable sort by bank (radix on a narrow copy)
    narrow = np.int8 if banks_total <= 128 else np.int16 if banks_total < 32767 else np.int64
    small = gbank.astype(narrow)
    by_bank = np.argsort(small, kind="stable")
    bank_sorted = small[by_bank]
    row_sorted = row[by_bank]
    has_prev = np.zeros(n, dtype=bool)
    np.equal(bank_sorted[1:], bank_sorted[:-1], out=has_prev[1:])
    same_row = has_prev.copy()
    same_row[1:] &= row_sorted[1:] == row_sorted[:-1]
    del row_sorted
    auto: np.ndarray | None = None
    if policy == "closed":
        auto_sorted = np.ones(n, dtype=bool)
        if n > 1:
            np.logical_not(same_row[1:], out=auto_sorted[:-1])
            auto_sorted[:-1] |= (by_bank[1:] - by_bank[:-1]) > config.read_queue
        prev_auto = np.zeros(n, dtype=bool)
        prev_auto[1:] = auto_sorted[:-1]
        hit = same_row & ~prev_auto
        conflict = has_prev & ~same_row & ~prev_auto
        auto = np.empty(n, dtype=bool)
        auto[by_bank] = auto_sorted
    else:
        hit = same_row
        conflict = has_prev
    need_sorted = np.flatnonzero(~hit)  # activating requests, by bank
    requests = by_bank[need_sorted]
    m = requests.size
    p_has_b = has_prev[need_sorted]
    p_b = np.where(p_has_b, by_bank[need_sorted - 1], 0)
    # q: the previous activating request of the same bank (it exists whenever p does)
    q_b = np.zeros(m, dtype=np.int64)
    if m > 1:
        q_b[1:] = np.where(p_has_b[1:], requests[:-1], 0)
    rank_p: np.ndarray | None = None
    if 8 * m > n:  # many activations: by marks and counts (no sort, no searches)
        need = np.zeros(n, dtype=bool)
        need[requests] = True
        idx = np.flatnonzero(need)
        position = np.empty(n, dtype=np.int64)
        position[requests] = np.arange(m, dtype=np.int64)
        to_time = position[idx]
        p = p_b[to_time]
        rank_p = np.cumsum(need, dtype=np.int64)[p]
    else:
        to_time = np.argsort(requests, kind="stable")  # a merge of the banks' ascending runs
        idx = requests[to_time]
        p = p_b[to_time]
    # ranks in the activating sequence: q's from the bank order, p's by a search
    rank_b = np.empty(m, dtype=np.int64)
    rank_b[to_time] = np.arange(1, m + 1, dtype=np.int64)
    rank_q_b = np.ones(m, dtype=np.int64)  # q = 0 (none): request 0, which always activates
    if m > 1:
        rank_q_b[1:] = np.where(p_has_b[1:], rank_b[:-1], 1)
    return Outcomes(auto=auto, idx=idx, p=p, p_has=p_has_b[to_time], q=q_b[to_time],
                    p_conflict=conflict[need_sorted][to_time],
                    rank_p=np.searchsorted(idx, p, side="right") if rank_p is None else rank_p,
                    rank_q=rank_q_b[to_time], by_bank=by_bank, bank_sorted=bank_sorted, hit_sorted=hit)
