"""Text plots: a min/max envelope in Braille dots, and one-line block sparklines.

A terminal cell holds a 2 × 4 grid of Braille dots, so a plot of W cells × H rows shows 2W data
columns at 4H vertical levels. Each data column is drawn as a vertical bar from its minimum to its
maximum (the envelope), so downsampled spikes stay visible. Unknown (NaN) columns are blank.
Pure functions returning strings; no terminal I/O.

Example:
    >>> import numpy as np
    >>> braille_envelope(np.array([0.0, 1.0]), np.array([0.0, 1.0]), lo=0.0, hi=1.0, height=1)
    ['⡈']
    >>> sparkline([0.0, 0.5, 1.0])
    '▁▅█'
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: Bit of each dot in a Braille cell, indexed [row 0..3 from the top][column 0..1].
_DOT_BITS = np.array([[0x01, 0x08], [0x02, 0x10], [0x04, 0x20], [0x40, 0x80]], dtype=np.int64)
_BRAILLE = np.array([chr(0x2800 + i) for i in range(256)])
_BLOCKS = "▁▂▃▄▅▆▇█"


def braille_envelope(
    min_w: np.ndarray, max_w: np.ndarray, *, lo: float, hi: float, height: int
) -> list[str]:
    """Rows (top first) of a Braille plot of the envelope ``[min_w, max_w]`` per data column.

    Args:
        min_w: per-data-column minimum (NaN = no data); its length should be even (2 per cell).
        max_w: per-data-column maximum.
        lo: the value at the bottom edge.
        hi: the value at the top edge.
        height: rows of text.

    Returns:
        ``height`` strings of ``ceil(len(min_w) / 2)`` characters each.
    """
    height = max(1, int(height))
    n = len(min_w)
    if n % 2:
        min_w = np.r_[min_w, np.nan]
        max_w = np.r_[max_w, np.nan]
        n += 1
    levels = 4 * height
    span = hi - lo if hi > lo else 1.0
    finite = np.isfinite(min_w) & np.isfinite(max_w)
    scale = (levels - 1) / span
    with np.errstate(invalid="ignore"):
        d_lo = np.clip(np.rint((np.where(finite, min_w, lo) - lo) * scale), 0, levels - 1).astype(np.int64)
        d_hi = np.clip(np.rint((np.where(finite, max_w, lo) - lo) * scale), 0, levels - 1).astype(np.int64)
    level = np.arange(levels - 1, -1, -1)[:, None]  # top row first, as levels from the bottom
    on = (level >= d_lo[None, :]) & (level <= d_hi[None, :]) & finite[None, :]
    cells = on.reshape(height, 4, n // 2, 2)
    codes = np.einsum("hrcw,rw->hc", cells.astype(np.int64), _DOT_BITS)
    chars = _BRAILLE[codes]
    return ["".join(row) for row in chars]


def sparkline(values: Sequence[float] | np.ndarray, *, lo: float | None = None, hi: float | None = None) -> str:
    """One line of block characters for ``values`` (NaN → space)."""
    arr = np.asarray(values, dtype=np.float64)
    if len(arr) == 0:
        return ""
    finite = arr[np.isfinite(arr)]
    if len(finite) == 0:
        return " " * len(arr)
    low = float(finite.min()) if lo is None else lo
    high = float(finite.max()) if hi is None else hi
    span = high - low
    out = []
    for v in arr:
        if not np.isfinite(v):
            out.append(" ")
        elif span <= 0:
            out.append(_BLOCKS[3])
        else:
            k = round((min(max(float(v), low), high) - low) / span * (len(_BLOCKS) - 1))
            out.append(_BLOCKS[k])
    return "".join(out)
