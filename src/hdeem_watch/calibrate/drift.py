"""Aging and outliers of a sensor group's fit: a CUSUM on its standardised residuals and a sibling
comparison of its currents. Pure: values and times in, alarms out.

**Residual CUSUM** (:class:`ResidualCusum`): each finished run gives the group's relative
out-of-sample residual ``r = measured / predicted − 1`` (predicted with the group's fit from
*before* the run). What the model leaves out is mostly common to the groups of a node (they run the
same kernels), so with at least two siblings the residual is taken against the median of the
siblings' residuals of the same run (``d = r − median(r_siblings)``). ``d`` is standardised by a
robust scale learnt over the first ``warmup`` runs (median |d| × 1.4826, at least ``scale_floor``)
and then followed slowly with clipped values; ``z`` is clipped to ±``clip`` so one odd run cannot
raise an alarm alone. Two one-sided CUSUMs ``S⁺ = max(0, S⁺ + z − k)``, ``S⁻ = max(0, S⁻ − z − k)``
alarm when one exceeds ``h``.

False-alarm rate: for i.i.d. N(0, 1) ``z``, Siegmund's approximation gives the one-sided in-control
average run length ``ARL₀ ≈ (e^{2kh'} − 2kh' − 1)/(2k²)`` with ``h' = h + 1.166``; at the defaults
``k = 0.5, h = 12`` that is ≈ 1.0·10⁶ runs one-sided, ≈ 5·10⁵ runs for the two-sided pair, i.e. a
false-alarm probability of ≈ 0.07 % per group over 360 runs (2 hours of 20-s runs), ≈ 0.3 % for
four groups. Residuals of a misspecified model are neither Gaussian nor independent, so the
benchmark (``benchmarks/bench_calibration.py``) measures the rate on misspecified data
(docs/calibration.md gives the figures). Delay: a step of ``δ`` scale units is detected after
≈ ``(h + 1.166)/(δ − k)`` runs.

**Sibling comparison** (:func:`sibling_outliers`): a group's calibrated current that lies more than
``tolerance`` (relative) from the median of its siblings' AND whose 95 % interval does not reach the
siblings' range. Parts of one type differ by ~±10 %, so the default tolerance is 25 %.

Example:
    >>> det = ResidualCusum("DDR_AB", warmup=3, h=10.0)
    >>> [det.update(d, t) for t, d in enumerate([0.01, -0.01, 0.0])]
    [None, None, None]
    >>> alarms = [det.update(0.2, 10 + t) for t in range(3)]
    >>> alarms[-1].group, alarms[-1].current, alarms[-1].direction
    ('DDR_AB', 'energy', 'up')
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

#: Normal-consistency factor of the median absolute deviation.
MAD_TO_SD = 1.4826


@dataclass(frozen=True)
class DriftAlarm:
    """One alarm of a group.

    Attributes:
        group: the sensor group (``DDR_CD``, ``DRAM1``, ``node``).
        current: the current concerned (``"energy"`` for a residual alarm: the group's energy as a
            whole moved against the model).
        kind: ``"residual-cusum"`` or ``"sibling"``.
        statistic: the CUSUM value (scale units), or the relative deviation from the siblings.
        threshold: what ``statistic`` crossed.
        time_ns: time of the run that raised it (ns).
        direction: ``"up"`` or ``"down"``.
    """

    group: str
    current: str
    kind: str
    statistic: float
    threshold: float
    time_ns: int
    direction: str

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {"group": self.group, "current": self.current, "kind": self.kind,
                "statistic": round(float(self.statistic), 6), "threshold": float(self.threshold),
                "time_ns": int(self.time_ns), "direction": self.direction}


def arl0_two_sided(k: float, h: float) -> float:
    """Siegmund's in-control average run length of the two-sided CUSUM for N(0, 1) input (runs).

    Example:
        >>> round(arl0_two_sided(0.5, 10.0), -3)
        71000.0
    """
    hp = h + 1.166
    one_sided = (math.exp(2 * k * hp) - 2 * k * hp - 1) / (2 * k * k)
    return one_sided / 2


class ResidualCusum:
    """Two-sided CUSUM on a group's standardised residuals (see the module docstring).

    Args:
        group: the group's name (put in the alarms).
        k: reference value (scale units; detects steps of ~2k best).
        h: decision threshold (scale units).
        warmup: runs used to learn the scale before any alarm.
        clip: standardised residuals are clipped to ±clip.
        scale_floor: smallest scale (relative residual), e.g. the sensor's accuracy.
        follow: weight of a new run in the scale after the warm-up (clipped at 3 scales).
    """

    def __init__(self, group: str, *, k: float = 0.5, h: float = 12.0, warmup: int = 20, clip: float = 4.0,
                 scale_floor: float = 0.002, follow: float = 0.02) -> None:
        self.group = group
        self.k, self.h, self.warmup, self.clip = float(k), float(h), int(warmup), float(clip)
        self.scale_floor, self.follow = float(scale_floor), float(follow)
        self.learning: list[float] = []
        self.scale = math.nan
        self.upper = 0.0
        self.lower = 0.0
        self.alarmed = False

    def update(self, residual: float, time_ns: int) -> DriftAlarm | None:
        """Feed one run's residual; the alarm when a CUSUM first crosses ``h`` (then none until
        :meth:`reset`)."""
        if not math.isfinite(residual):
            return None
        if len(self.learning) < self.warmup:
            self.learning.append(float(residual))
            if len(self.learning) == self.warmup:
                centre = float(np.median(self.learning))
                mad = float(np.median(np.abs(np.array(self.learning) - centre)))
                self.scale = max(MAD_TO_SD * mad, self.scale_floor)
            return None
        z = max(-self.clip, min(self.clip, residual / self.scale))
        self.upper = max(0.0, self.upper + z - self.k)
        self.lower = max(0.0, self.lower - z - self.k)
        if abs(z) < 3.0:  # follow slow changes of the scale, not the drift itself
            self.scale = max(self.scale_floor, math.sqrt((1 - self.follow) * self.scale ** 2
                                                         + self.follow * (z * self.scale) ** 2))
        if self.alarmed or max(self.upper, self.lower) <= self.h:
            return None
        self.alarmed = True
        up = self.upper >= self.lower
        return DriftAlarm(self.group, "energy", "residual-cusum", max(self.upper, self.lower), self.h, int(time_ns),
                          "up" if up else "down")

    def restart(self) -> None:
        """Zero the sums, keep the learnt scale (a sibling's drift was found: what the sums took
        from it while it was still a reference goes)."""
        self.upper = self.lower = 0.0

    def reset(self) -> None:
        """Start again (after a replaced DIMM or a calibration reset)."""
        self.learning.clear()
        self.scale = math.nan
        self.upper = self.lower = 0.0
        self.alarmed = False

    def to_dict(self) -> dict[str, Any]:
        """State for the ``calib`` body and persistence."""
        return {"k": self.k, "h": self.h, "warmup": self.warmup, "learning": list(self.learning),
                "scale": None if math.isnan(self.scale) else self.scale, "upper": self.upper,
                "lower": self.lower, "alarmed": self.alarmed}

    @classmethod
    def from_dict(cls, group: str, data: Mapping[str, Any]) -> ResidualCusum:
        """Inverse of :meth:`to_dict`."""
        det = cls(group, k=float(data["k"]), h=float(data["h"]), warmup=int(data["warmup"]))
        det.learning = [float(v) for v in data.get("learning", [])]
        det.scale = math.nan if data.get("scale") is None else float(data["scale"])
        det.upper, det.lower = float(data.get("upper", 0.0)), float(data.get("lower", 0.0))
        det.alarmed = bool(data.get("alarmed", False))
        return det


def sibling_residuals(residuals: Mapping[str, float], *, exclude: Collection[str] = ()) -> dict[str, float]:
    """Each group's residual against the median of its siblings' (as is, with fewer than two
    siblings). NaN residuals stay NaN and are not used as siblings; nor are the groups in
    ``exclude`` (those that drift already: the median of three siblings of which one drifts is
    biased towards it by about half a standard deviation, enough for the CUSUM to alarm on a
    healthy group after a few hundred runs).

    Example:
        >>> sibling_residuals({"a": 0.05, "b": 0.01, "c": 0.0, "d": 0.02})["a"]
        0.04
    """
    finite = {g: r for g, r in residuals.items() if math.isfinite(r) and g not in exclude}
    out: dict[str, float] = {}
    for group, r in residuals.items():
        others = [v for g, v in finite.items() if g != group]
        out[group] = r - float(np.median(others)) if len(others) >= 2 and math.isfinite(r) else r
    return out


def sibling_outliers(currents: Mapping[str, Mapping[str, tuple[float, float, float]]], *, time_ns: int,
                     tolerance: float = 0.25) -> list[DriftAlarm]:
    """Groups whose current left the spread of their siblings.

    Args:
        currents: group → current → ``(value, ci_low, ci_high)`` (A), identifiable ones only.
        time_ns: time put in the alarms.
        tolerance: relative distance from the siblings' median needed on top of the interval test.

    Returns:
        One alarm per (group, current) that is further than ``tolerance`` from the median of at
        least two siblings and whose interval lies outside the siblings' [min, max].
    """
    alarms: list[DriftAlarm] = []
    names = sorted({name for per in currents.values() for name in per})
    for name in names:
        have = {g: per[name] for g, per in currents.items() if name in per and math.isfinite(per[name][0])}
        for group, (value, lo, hi) in have.items():
            others = [v[0] for g, v in have.items() if g != group]
            if len(others) < 2:
                continue
            median = float(np.median(others))
            if median <= 0:
                continue
            deviation = value / median - 1
            lo = value if not math.isfinite(lo) else lo
            hi = value if not math.isfinite(hi) else hi
            outside = lo > max(others) or hi < min(others)
            if abs(deviation) > tolerance and outside:
                alarms.append(DriftAlarm(group, name, "sibling", deviation, tolerance, int(time_ns),
                                         "up" if deviation > 0 else "down"))
    return alarms


def identifiable_currents(fit: Any) -> dict[str, tuple[float, float, float]]:
    """``{current: (value, ci_low, ci_high)}`` of a :class:`~hdeem_watch.calibrate.result.FitResult`'s
    identifiable currents (input of :func:`sibling_outliers`)."""
    out: dict[str, tuple[float, float, float]] = {}
    for j, name in enumerate(fit.currents):
        if bool(fit.identifiable[j]):
            out[name] = (float(fit.calibrated_a[j]), float(fit.ci95_a[j, 0]), float(fit.ci95_a[j, 1]))
    return out
