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
    """Bucket samples (sorted by time) into ``width`` equal time columns over ``[t0_ns, t1_ns)``.

    Samples outside the window are ignored; NaN samples count as unknown (they never become the
    minimum or maximum, and a column of only NaN stays NaN).
    """
    width = max(1, int(width))
    span = max(1, int(t1_ns) - int(t0_ns))
    mins = np.full(width, np.nan)
    maxs = np.full(width, np.nan)
    means = np.full(width, np.nan)
    if len(t_ns) == 0:
        return Columns(int(t0_ns), int(t1_ns), mins, maxs, means)
    keep = (t_ns >= t0_ns) & (t_ns < t1_ns) & np.isfinite(power_w)
    t = t_ns[keep]
    p = power_w[keep]
    if len(t) == 0:
        return Columns(int(t0_ns), int(t1_ns), mins, maxs, means)
    col = ((t - int(t0_ns)).astype(np.float64) * (width / span)).astype(np.int64)
    np.clip(col, 0, width - 1, out=col)
    order = np.argsort(col, kind="stable")
    col = col[order]
    p = p[order]
    starts = np.flatnonzero(np.r_[True, col[1:] != col[:-1]])
    used = col[starts]
    mins[used] = np.minimum.reduceat(p, starts)
    maxs[used] = np.maximum.reduceat(p, starts)
    counts = np.diff(np.r_[starts, len(p)])
    means[used] = np.add.reduceat(p, starts) / counts
    return Columns(int(t0_ns), int(t1_ns), mins, maxs, means)


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
