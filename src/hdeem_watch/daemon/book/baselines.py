"""Idle baselines per channel, with their spread: pure functions over sample arrays.

A baseline is the power a channel draws when the node does nothing: the reference a run's energy
is compared against, and the row that pins the standby currents in the calibration. It comes from

* an explicit idle window: ``baseline.measure`` (origin ``"measured"``: nothing runs, the CPUs
  are idle too) or a run with kernel ``idle`` (origin ``"idle-run"``: the DIMMs are idle, the
  benchmark's threads may not be); its mean is the window's exact energy divided by its duration;
* a *quiet period* found in the recent samples while no run is going on: the window with the
  lowest mean among those whose spread (standard deviation) is small; origin ``"quiet"``.

Example:
    >>> import numpy as np
    >>> p = np.r_[np.full(200, 9.0), np.full(200, 4.0) + np.tile([0.0, 0.125], 100)]
    >>> window = quiet_window(p, rate_hz=100.0, window_s=1.0, max_spread_w=0.25)
    >>> b = baseline_from_samples(p[window[0]:window[1]], t_ns=0, origin="quiet")
    >>> baseline_from_samples(np.array([np.nan]), t_ns=0, origin="quiet") is None
    True
    >>> round(b.power_w, 4), round(b.spread_w, 4), b.n
    (4.0625, 0.0625, 100)
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

Origin = Literal["idle-run", "measured", "quiet"]
ORIGINS = ("idle-run", "measured", "quiet")
#: Origins of an explicit idle window (they win over quiet periods).
WINDOW_ORIGINS = ("idle-run", "measured")


@dataclass(frozen=True)
class Baseline:
    """The idle power of one channel.

    Attributes:
        power_w: mean idle power (NaN = unknown).
        spread_w: standard deviation of the samples in the window.
        n: number of (finite) samples.
        t_ns: wall-clock time of the end of the window.
        origin: ``"idle-run"``, ``"measured"`` or ``"quiet"``.
    """

    power_w: float
    spread_w: float
    n: int
    t_ns: int
    origin: Origin

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (NaN stays NaN; the protocol encoder sends null)."""
        return {"power_w": self.power_w, "spread_w": self.spread_w, "n": self.n, "t_ns": self.t_ns, "origin": self.origin}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Baseline:
        """Inverse of :meth:`to_dict` (None → NaN)."""
        origin = data.get("origin")
        if origin not in ORIGINS:
            raise ValueError(f"baseline origin {origin!r}: expected one of {ORIGINS}")
        return cls(
            power_w=_float(data.get("power_w")),
            spread_w=_float(data.get("spread_w")),
            n=int(data.get("n") or 0),
            t_ns=int(data.get("t_ns") or 0),
            origin=origin,
        )


def _float(value: Any) -> float:
    return math.nan if value is None else float(value)


def baseline_from_samples(
    power_w: np.ndarray,
    *,
    t_ns: int,
    origin: Origin,
    energy_j: float | None = None,
    window_s: float | None = None,
) -> Baseline | None:
    """A baseline from the samples of an idle window; None when the window has no finite sample.

    A window over a sensor gap measured nothing: it must not become a 0 W (or energy-only)
    baseline that replaces a real one.

    Args:
        power_w: the window's samples (NaN ignored).
        t_ns: end of the window (wall clock ns).
        origin: ``"idle-run"`` or ``"quiet"``.
        energy_j: the window's exact energy; with ``window_s`` the mean is ``energy_j / window_s``
            (no sample lost between polls can bias it). Otherwise the sample mean.
        window_s: the window's duration in seconds.
    """
    values = np.asarray(power_w, dtype=float)
    finite = values[np.isfinite(values)]
    n = int(finite.size)
    if n == 0:
        return None
    spread = float(np.std(finite)) if n > 1 else math.nan
    if energy_j is not None and window_s is not None and window_s > 0 and math.isfinite(energy_j):
        mean = float(energy_j) / float(window_s)
    else:
        mean = float(np.mean(finite))
    return Baseline(power_w=mean, spread_w=spread, n=n, t_ns=int(t_ns), origin=origin)


def window_stats(power_w: np.ndarray, width: int, step: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean and standard deviation of windows of ``width`` samples every ``step`` samples.

    Returns ``(starts, means, stds)``; windows containing NaN get NaN. O(n) with cumulative sums.
    """
    values = np.asarray(power_w, dtype=float)
    if width <= 0 or step <= 0:
        raise ValueError("width and step must be > 0")
    if values.size < width:
        empty = np.empty(0)
        return np.empty(0, dtype=np.int64), empty, empty
    bad = ~np.isfinite(values)
    clean = np.where(bad, 0.0, values)
    # Centre on the mean before summing squares (the two-pass form) so the variance does not cancel
    # catastrophically. (Not the median: its first call imports numpy.ma, 10-15 ms in the poll loop.)
    centre = float(np.mean(clean[~bad])) if (~bad).any() else 0.0
    shifted = clean - centre
    c1 = np.concatenate(([0.0], np.cumsum(shifted)))
    c2 = np.concatenate(([0.0], np.cumsum(shifted * shifted)))
    cb = np.concatenate(([0], np.cumsum(bad)))
    starts = np.arange(0, values.size - width + 1, step, dtype=np.int64)
    s1 = c1[starts + width] - c1[starts]
    s2 = c2[starts + width] - c2[starts]
    nbad = cb[starts + width] - cb[starts]
    mean = s1 / width
    var = np.maximum(s2 / width - mean * mean, 0.0)
    mean = mean + centre
    std = np.sqrt(var)
    mean[nbad > 0] = np.nan
    std[nbad > 0] = np.nan
    return starts, mean, std


def quiet_window(
    power_w: np.ndarray,
    *,
    rate_hz: float,
    window_s: float,
    max_spread_w: float,
    max_rel_spread: float = 0.05,
) -> tuple[int, int] | None:
    """The quietest idle window in ``power_w``: ``(start, stop)`` sample indices, or None.

    A window is quiet when its standard deviation is at most ``max(max_spread_w, max_rel_spread ×
    mean)``; among quiet windows (stepped by a quarter window) the one with the lowest mean wins —
    on a node that is not idle the lowest quiet level is the closest to idle.
    """
    width = max(2, round(window_s * rate_hz))
    starts, mean, std = window_stats(power_w, width, max(1, width // 4))
    if starts.size == 0:
        return None
    limit = np.maximum(max_spread_w, max_rel_spread * np.abs(mean))
    ok = np.isfinite(std) & (std <= limit)
    if not ok.any():
        return None
    candidates = np.flatnonzero(ok)
    best = candidates[np.argmin(mean[candidates])]
    start = int(starts[best])
    return start, start + width


def merge(current: Baseline | None, new: Baseline, *, max_age_ns: int = 3600 * 10**9) -> Baseline | None:
    """The baseline to keep after ``new`` arrives.

    A baseline of an explicit idle window (``idle-run`` or ``measured``) always wins over a quiet one
    and replaces an older window baseline; a quiet baseline replaces a quiet one when it is lower
    (closer to idle) or the kept one is older than ``max_age_ns``; it replaces a window baseline
    only when that is older than ``max_age_ns``. Baselines without a finite power or without samples never replace anything.
    """
    if not math.isfinite(new.power_w) or new.n <= 0:
        return current
    if current is None or not math.isfinite(current.power_w):
        return new
    stale = new.t_ns - current.t_ns > max_age_ns
    if new.origin in WINDOW_ORIGINS:
        return new
    if current.origin == "quiet":
        return new if (new.power_w <= current.power_w or stale) else current
    return new if stale else current


def baselines_body(baselines: Mapping[str, Baseline]) -> dict[str, Any]:
    """The ``baseline`` topic body: ``{"channels": {name: {...}}}``."""
    return {"channels": {name: b.to_dict() for name, b in sorted(baselines.items())}}
