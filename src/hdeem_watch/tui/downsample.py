"""Min/max-preserving downsampling of a time series onto a fixed number of plot columns.

A plot of W columns covering a window [t0, t1) gets, per column, the minimum, the maximum and the
mean of every sample that falls in it: a 1 ms spike in a 60 s window still shows up as the top of
its column's envelope instead of being averaged away. Columns without samples are NaN (unknown,
not zero). Pure numpy; no I/O.

Example:
    >>> import numpy as np
    >>> t = np.arange(10, dtype=np.int64)
    >>> p = np.array([1, 1, 9, 1, 1, 1, 1, 0, 1, 1], dtype=float)
    >>> cols = minmax_columns(t, p, t0_ns=0, t1_ns=10, width=2)
    >>> cols.min_w.tolist(), cols.max_w.tolist()
    ([1.0, 0.0], [9.0, 1.0])
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class Columns:
    """Per-column envelope of a window.

    Attributes:
        t0_ns: window start (inclusive).
        t1_ns: window end (exclusive).
        min_w: per-column minimum (NaN where the column has no finite sample).
        max_w: per-column maximum.
        mean_w: per-column mean of the finite samples.
    """

    t0_ns: int
    t1_ns: int
    min_w: np.ndarray
    max_w: np.ndarray
    mean_w: np.ndarray

    @property
    def width(self) -> int:
        """Number of columns."""
        return len(self.min_w)


def minmax_columns(t_ns: np.ndarray, power_w: np.ndarray, *, t0_ns: int, t1_ns: int, width: int) -> Columns:
    """Bucket samples into ``width`` equal time columns over ``[t0_ns, t1_ns)``.

    Column ``k`` holds the samples with ``edge[k] <= t < edge[k + 1]``, ``edge[k] = t0 + k·span//width``.
    Samples outside the window are ignored; NaN samples count as unknown (they never become the
    minimum or maximum, and a column of only NaN stays NaN). Times should be sorted (they are
    sorted here if not). Cost: a few linear passes (``searchsorted`` + ``reduceat``), no per-sample
    Python.
    """
    width = max(1, int(width))
    t0 = int(t0_ns)
    span = max(1, int(t1_ns) - t0)
    mins = np.full(width, np.nan)
    maxs = np.full(width, np.nan)
    means = np.full(width, np.nan)
    if len(t_ns) == 0:
        return Columns(t0, int(t1_ns), mins, maxs, means)
    if len(t_ns) > 1 and np.any(t_ns[1:] < t_ns[:-1]):
        order = np.argsort(t_ns, kind="stable")
        t_ns, power_w = t_ns[order], power_w[order]
    edges = t0 + (np.arange(width + 1, dtype=np.int64) * span) // width
    idx = np.searchsorted(t_ns, edges, side="left")
    lo, hi = int(idx[0]), int(idx[-1])
    if hi <= lo:
        return Columns(t0, int(t1_ns), mins, maxs, means)
    p = power_w[lo:hi]
    starts = idx[:-1] - lo
    used = idx[1:] > idx[:-1]
    s = starts[used]
    finite = np.isfinite(p)
    with np.errstate(invalid="ignore", divide="ignore"):
        col_min = np.minimum.reduceat(np.where(finite, p, np.inf), s)
        col_max = np.maximum.reduceat(np.where(finite, p, -np.inf), s)
        counts = np.add.reduceat(finite.astype(np.int64), s)
        sums = np.add.reduceat(np.where(finite, p, 0.0), s)
        col_mean = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    col_min[counts == 0] = np.nan
    col_max[counts == 0] = np.nan
    mins[used] = col_min
    maxs[used] = col_max
    means[used] = col_mean
    return Columns(t0, int(t1_ns), mins, maxs, means)


def finite_range(*arrays: np.ndarray) -> tuple[float, float] | None:
    """``(lowest, highest)`` finite value over the arrays, None when there is none."""
    lo = np.inf
    hi = -np.inf
    for a in arrays:
        finite = a[np.isfinite(a)]
        if len(finite):
            lo = min(lo, float(finite.min()))
            hi = max(hi, float(finite.max()))
    if lo > hi:
        return None
    return lo, hi


class ColumnCache:
    """Plot columns aligned to absolute time, computed once when complete.

    Column ``g`` covers ``[g·col_ns, (g+1)·col_ns)`` for the window's column span ``col_ns``, so
    a column that is complete (the channel's newest sample is past its end) never changes and is
    kept; each call computes only the columns still filling (usually the last one or two). This
    also keeps the plot from shimmering: columns do not shift by a fraction each frame.
    A zoom or resize (another ``col_ns``) starts afresh.
    """

    def __init__(self) -> None:
        self._col_ns = 0
        self._done: dict[int, tuple[float, float, float]] = {}

    def columns(
        self,
        window: Callable[[int, int], tuple[np.ndarray, np.ndarray]],
        *,
        t1_ns: int,
        window_ns: int,
        width: int,
        newest_ns: int | None,
    ) -> Columns:
        """The ``width`` columns ending with the one that holds ``t1_ns``.

        Args:
            window: returns the (sorted) samples of ``[from_ns, to_ns)``.
            t1_ns: the newest time to show.
            window_ns: the time span of the plot.
            width: number of columns.
            newest_ns: time of the channel's newest sample (None if none).
        """
        width = max(1, int(width))
        col_ns = max(1, -(-int(window_ns) // width))
        if col_ns != self._col_ns:
            self._col_ns = col_ns
            self._done.clear()
        g_end = int(t1_ns) // col_ns + 1
        g_start = g_end - width
        first_missing = next((g for g in range(g_start, g_end) if g not in self._done), g_end)
        mins = np.full(width, np.nan)
        maxs = np.full(width, np.nan)
        means = np.full(width, np.nan)
        for k, g in enumerate(range(g_start, first_missing)):
            mins[k], maxs[k], means[k] = self._done[g]
        if first_missing < g_end:
            t, p = window(first_missing * col_ns, g_end * col_ns)
            fresh = minmax_columns(t, p, t0_ns=first_missing * col_ns, t1_ns=g_end * col_ns, width=g_end - first_missing)
            k0 = first_missing - g_start
            mins[k0:] = fresh.min_w
            maxs[k0:] = fresh.max_w
            means[k0:] = fresh.mean_w
            if newest_ns is not None:
                for i, g in enumerate(range(first_missing, g_end)):
                    if (g + 1) * col_ns <= newest_ns:
                        self._done[g] = (float(fresh.min_w[i]), float(fresh.max_w[i]), float(fresh.mean_w[i]))
        if len(self._done) > 4 * width:
            for g in [g for g in self._done if g < g_start]:
                del self._done[g]
        return Columns(g_start * col_ns, g_end * col_ns, mins, maxs, means)
