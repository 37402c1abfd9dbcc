"""Activation spacing: tRRD_S, tRRD_L and tFAW on the ACT commands of each rank (vectorised core).

JEDEC's activation rules, per rank (JESD79-4 §4.x / JESD79-5 §4.x "ACT to ACT"): two ACTs to
different bank groups at least tRRD_S apart, to one bank group at least tRRD_L apart, and at most
four ACTs in any window of tFAW. :func:`space_activations` takes each ACT's earliest cycle and gives
the earliest cycles that obey the rules, issuing each rank's ACTs in the order of their earliest
cycles (first come, first served; ties in input order), and moves none into a refresh window (an
ACT that would land while a refresh holds the rank waits for its end).

The rules are a max-plus recurrence over each rank's ACTs in order. Where an ACT comes at least
the longest rule after the latest its predecessors could be issued, nothing before it can delay it
or anything after it: the sequence falls apart into independent runs there (found by one cumulative
maximum), an ACT alone in its run keeps its earliest cycle, and the recurrence runs one ACT at a
time only over the runs of more than one (exact; a stream whose ACTs are rarely closer than the
rules costs a few array operations).

Example:
    >>> import numpy as np
    >>> rules = ActRules(rrd_s=4, rrd_l=6, faw=20)
    >>> space_activations(np.array([0, 0, 0, 0, 0]), np.zeros(5, int), np.array([0, 1, 2, 3, 0]), rules).tolist()
    [0, 4, 8, 12, 20]
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

#: Rounds of the upper bound through refresh windows before every ACT counts as coupled.
_BOUND_ROUNDS = 4


@dataclass(frozen=True)
class ActRules:
    """tRRD_S, tRRD_L and tFAW in cycles (0: no such rule).

    Attributes:
        rrd_s: ACT to ACT, different bank groups of one rank.
        rrd_l: ACT to ACT, one bank group.
        faw: the window in which a rank may issue at most four ACTs.
    """

    rrd_s: int
    rrd_l: int
    faw: int

    @property
    def binding(self) -> bool:
        """Whether any rule can delay an ACT."""
        return max(self.rrd_s, self.rrd_l, self.faw) > 0


@dataclass(frozen=True)
class RefreshWindows:
    """Cycles in which no ACT may be issued: ``[k × refi, k × refi + length)`` for ``k >= first``
    (all-bank refresh ``k``: PREA, then REFA for tRFC)."""

    refi: int
    length: int
    first: int

    def push(self, cycle: np.ndarray) -> np.ndarray:
        """``cycle`` with every entry inside a window moved to that window's end."""
        k = cycle // self.refi
        inside = (k >= self.first) & (cycle - k * self.refi < self.length)
        return np.where(inside, k * self.refi + self.length, cycle)


def space_activations(earliest: np.ndarray, rank: np.ndarray, group: np.ndarray, rules: ActRules,
                      windows: RefreshWindows | None = None) -> np.ndarray:
    """Earliest ACT cycles at or after ``earliest`` that obey ``rules`` (see the module doc).

    Args:
        earliest: earliest cycle of each ACT (int64).
        rank: its rank; ``group``: its bank group, numbered uniquely over the ranks.
        rules: tRRD_S, tRRD_L, tFAW.
        windows: refresh windows no ACT may fall in (``None``: none).

    Returns:
        The ACT cycles, in the input's order; per rank they keep the order of ``earliest``.
    """
    n = earliest.size
    if n == 0 or (not rules.binding and windows is None):
        return earliest.copy()
    order = np.lexsort((earliest, rank))
    base = earliest[order].astype(np.int64)
    if windows is not None:
        base = windows.push(base)
    r, g = rank[order], group[order]
    coupled = _coupled(base, _starts(r), max(rules.rrd_s, rules.rrd_l, rules.faw), windows)
    cycle = base.copy()
    if coupled.any():
        cycle[coupled] = _plain_loop(base[coupled], r[coupled], g[coupled], rules, windows)
    spaced = np.empty(n, dtype=np.int64)
    spaced[order] = cycle
    return spaced


def _coupled(base: np.ndarray, rank_start: np.ndarray, gap: int, windows: RefreshWindows | None) -> np.ndarray:
    """The ACTs a rule may delay: those of every run that does not start ``gap`` after the latest
    its predecessors could be issued (an upper bound: each ACT ``gap`` after the one before it).

    An ACT that starts such a run, with the one after it starting the next, stays at ``base``; the
    runs are independent of each other (``gap`` is the longest rule).
    """
    bound = base
    for _ in range(_BOUND_ROUNDS):  # the bound with refresh windows: chained, pushed, until stable
        chained = _chain(bound, np.full(base.size, gap, dtype=np.int64), rank_start)
        pushed = windows.push(chained) if windows is not None else chained
        if np.array_equal(pushed, bound):
            break
        bound = np.maximum(pushed, base)
    else:  # a chain across many windows: one run
        return np.ones(base.size, dtype=bool)
    run_start = rank_start.copy()
    run_start[1:] |= base[1:] >= bound[:-1] + gap
    alone = run_start.copy()
    alone[:-1] &= run_start[1:]
    return ~alone


def _starts(key: np.ndarray) -> np.ndarray:
    """Where a run of equal ``key`` starts."""
    starts = np.ones(key.size, dtype=bool)
    starts[1:] = key[1:] != key[:-1]
    return starts


def _chain(cycle: np.ndarray, steps: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Least ``x >= cycle`` with ``x[k] >= x[k-1] + steps[k]`` except where a segment ``starts``.

    Solved as ``R + cummax(cycle - R)`` with ``R`` the cumulative steps, the segments kept apart by
    an offset larger than the values' span.
    """
    if cycle.size == 0:
        return cycle
    steps = np.where(starts, 0, steps)
    reach = np.cumsum(steps)
    free = cycle - reach
    segment = np.cumsum(starts) - 1
    low = int(free.min())
    span = int(free.max()) - low + 1
    if span * (int(segment[-1]) + 1) >= 1 << 62:  # offsets would overflow: segment by segment
        out = cycle.copy()
        bounds = [*np.flatnonzero(starts).tolist(), cycle.size]
        for lo, hi in itertools.pairwise(bounds):
            out[lo:hi] = reach[lo:hi] + np.maximum.accumulate(free[lo:hi])
        return out
    lifted = free - low + segment * span
    return np.maximum.accumulate(lifted) - segment * span + low + reach


def _plain_loop(cycle: np.ndarray, rank: np.ndarray, group: np.ndarray, rules: ActRules,
                windows: RefreshWindows | None) -> np.ndarray:
    """The same rules, one ACT at a time (``cycle`` sorted by rank, then earliest cycle)."""
    rrd_s, rrd_l, faw = rules.rrd_s, rules.rrd_l, rules.faw
    refi, length, first = (windows.refi, windows.length, windows.first) if windows is not None else (1, 0, 0)
    out: list[int] = []
    recent: dict[int, list[int]] = {}
    last_of_group: dict[int, int] = {}
    for t, r, g in zip(cycle.tolist(), rank.tolist(), group.tolist()):
        mine = recent.setdefault(r, [])
        while True:
            if mine:
                t = max(t, mine[-1] + rrd_s)
                if len(mine) >= 4:
                    t = max(t, mine[-4] + faw)
            if g in last_of_group:
                t = max(t, last_of_group[g] + rrd_l)
            k = t // refi
            if k < first or t - k * refi >= length:
                break
            t = k * refi + length
        out.append(t)
        mine.append(t)
        if len(mine) > 4:
            del mine[0]
        last_of_group[g] = t
    return np.array(out, dtype=np.int64)


@dataclass(frozen=True)
class RecentActs:
    """The last activations of a chunk that the rules still see from the next one: the last four of
    each rank and the last of each bank group (cycle, rank, bank group; arrays of one length)."""

    cycle: np.ndarray
    rank: np.ndarray
    group: np.ndarray


def recent_activations(cycle: np.ndarray, rank: np.ndarray, group: np.ndarray) -> RecentActs:
    """The :class:`RecentActs` of a chunk's activations (any order)."""
    order = np.lexsort((cycle, rank))
    cycle, rank, group = cycle[order], rank[order], group[order]
    n = cycle.size
    last_of_rank = np.ones(n, dtype=bool)
    last_of_rank[:-1] = rank[1:] != rank[:-1]
    run_end = np.minimum.accumulate(np.where(last_of_rank, np.arange(n), n)[::-1])[::-1]
    last_of_group = np.zeros(n, dtype=bool)
    by_group = np.lexsort((cycle, group))
    ends = np.ones(n, dtype=bool)
    ends[:-1] = group[by_group][1:] != group[by_group][:-1]
    last_of_group[by_group[ends]] = True
    keep = (run_end - np.arange(n) < 4) | last_of_group
    return RecentActs(cycle=cycle[keep], rank=rank[keep], group=group[keep])
