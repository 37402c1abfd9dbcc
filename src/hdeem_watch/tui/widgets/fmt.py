"""Number formatting shared by the widgets: fixed widths, unknown shown as "–" (never 0)."""

from __future__ import annotations

import math

from rich.text import Text

UNKNOWN = "–"


def fixed(value: float, width: int, decimals: int = 1, *, sign: bool = False, suffix: str = "") -> str:
    """``value`` right-aligned in ``width`` characters, "–" when not finite."""
    if not math.isfinite(value):
        return (UNKNOWN + suffix).rjust(width)
    text = f"{value:+.{decimals}f}" if sign else f"{value:.{decimals}f}"
    return (text + suffix).rjust(width)


def percent(value: float, width: int = 6) -> str:
    """A ratio as a signed percentage, "–" when unknown."""
    if not math.isfinite(value):
        return UNKNOWN.rjust(width)
    return f"{value * 100:+.0f}%".rjust(width) if abs(value) >= 0.095 else f"{value * 100:+.1f}%".rjust(width)


def energy(value_j: float, width: int = 7) -> str:
    """Joules with an adaptive number of decimals."""
    if not math.isfinite(value_j):
        return UNKNOWN.rjust(width)
    if abs(value_j) >= 1000:
        return f"{value_j / 1000:.2f}k".rjust(width)
    if abs(value_j) >= 100:
        return f"{value_j:.0f}".rjust(width)
    if abs(value_j) >= 10:
        return f"{value_j:.1f}".rjust(width)
    return f"{value_j:.2f}".rjust(width)


def per_second(value: float, width: int = 6) -> str:
    """A rate with an SI prefix (``950``, ``12.3k``, ``1.05G``), "–" when unknown.

    >>> per_second(1.234e9), per_second(float("nan"))
    (' 1.23G', '     –')
    """
    if not math.isfinite(value):
        return UNKNOWN.rjust(width)
    for scale, prefix in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if abs(value) >= scale:
            digits = 2 if abs(value) < 10 * scale else 1 if abs(value) < 100 * scale else 0
            return f"{value / scale:.{digits}f}{prefix}".rjust(width)
    return f"{value:.0f}".rjust(width)


def megabytes(n_bytes: int) -> str:
    """Resident memory in MB ("–" when unknown)."""
    return f"{n_bytes / 1e6:.0f}MB" if n_bytes > 0 else UNKNOWN


def duration(seconds: float) -> str:
    """Seconds, compact (``1.5s``, ``42s``, ``3m05``)."""
    if not math.isfinite(seconds):
        return UNKNOWN
    if seconds < 10:
        return f"{seconds:.1f}s"
    if seconds < 600:
        return f"{seconds:.0f}s"
    return f"{int(seconds // 60)}m{int(seconds % 60):02d}"


def crop(text: Text, width: int) -> Text:
    """Every line of ``text`` cut to ``width`` cells (the panels never wrap)."""
    lines = text.split("\n", allow_blank=True)
    for line in lines:
        line.truncate(max(1, width), overflow="crop")
    return Text("\n", no_wrap=True).join(lines)
