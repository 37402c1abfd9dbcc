"""Aging and outliers of a sensor group's fit: a CUSUM on same-kind residual changes against the
siblings, and a comparison of each group's current changes with its siblings'. Pure: values and
times in, alarms out.

**Residual CUSUM** (:class:`ResidualCusum`, fed by
:class:`~hdeem_watch.calibrate.groups.GroupCalibrators`). What the model leaves out is a large,
*systematic* error per kind of run (on the simulated node −7 … +18 % per kernel and thread count,
different for the two sockets: threads fill socket 0 first), so the plain out-of-sample residual
of a run says little about aging. Against the group's own earlier run *of the same kind*, evaluated
with the *same* (current) fit, it does: the input of a run is

    x_g = log(m_g / p_g) − mean log(m'_g / p'_g)

(``m`` measured, ``p`` predicted by group ``g``'s fit before the run; primed: the group's last up to
three runs of the same kind — kernel, threads, CPUs), i.e. how much the group's energy changed
since its earlier runs of that kind beyond what the model expects from their lengths. The kind's
systematic misfit cancels, and so does most of any change of the fit. What is common to the groups
(temperature, the node's own load) is taken out by the median of the siblings' changes in the same
run, ``d_g = x_g − median(x_h)`` (at least two siblings; a group that alarmed already is no
sibling), weighted by ``√P`` (the run's mean power in W: the change's noise falls about as
``1/√P``), standardised by a scale learnt over the first ``warmup`` values (:func:`robust_sd`, at
least ``scale_floor``) and then followed slowly; ``z`` is clipped to ±``clip`` so one odd run
cannot alarm alone; when the scale is learnt the warm-up's values go through the sums too. Two
one-sided CUSUMs ``S⁺ = max(0, S⁺ + z − k)``, ``S⁻ = max(0, S⁻ − z − k)`` alarm when one exceeds
``h``.

Statistics. For i.i.d. N(0, 1) ``z`` Siegmund's approximation gives the one-sided in-control average
run length ``ARL₀ ≈ (e^{2kh'} − 2kh' − 1)/(2k²)``, ``h' = h + 1.166`` (:func:`arl0_two_sided`: half
that for the two-sided pair). At the defaults ``k = 1, h = 10`` that is ≈ 1.2·10⁹ runs per group,
a false-alarm probability of ≈ 10⁻⁴ % per group in 1000 runs (2 sim-hours of the demo). The ``x`` of successive runs of one kind share runs (correlation −1/9 with three
references), which makes partial sums smaller than for i.i.d. input; the residuals of a misspecified
model are not Gaussian (kurtosis 4–10 on the sim), which the clip bounds; the scale is estimated
from 24 values (a 20 % underestimate turns the nominal 1.2·10⁹ into ≈ 9·10⁵). The rate on the
misspecified sim is measured by ``benchmarks/bench_calibration.py`` (docs/calibration.md).
Detection: a pair whose currents grow at a rate ``ρ`` shifts ``d`` by about ``ρ·Δt·(L + 1)/2``
(``Δt``: the time between two runs of one kind, ``L`` ≤ 3 references) and is found after ≈
``(h + 1.166)/(δ − k)`` comparisons (``δ`` in scale units); a change slower than ``k`` scales per
``Δt`` is not (the fits' ``drift()`` follows such).

**Sibling change** (:func:`sibling_changes`): each group's identifiable currents are compared with
its *own* reference fit (taken when the group's detectors start) relative to its siblings' changes
since theirs: ``Δ_g = log(I_g/I_g,ref) − median_h log(I_h/I_h,ref)``. Levels are not compared: parts
of one type differ by ±10 % and what the model leaves out (sensor offsets, power-down) shifts each
pair's effective background currents by more (up to 40 % on the sim), while a healthy pair's
currents keep their ratio to its siblings'. An alarm needs ``|Δ_g|`` beyond ``tolerance`` (default
15 %) *and* beyond ``z`` (default 4) standard errors, ``se² = se_now² + se_ref²`` from the two fits'
95 % intervals (log scale). Each (group, current) alarms once.

Example:
    >>> det = ResidualCusum("DDR_AB", warmup=3, h=6.0)
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


def robust_sd(values: Collection[float]) -> float:
    """The standard deviation of ``values`` with outliers limited: the RMS of the deviations from
    the median, each clipped to 3 MADs (× 1.4826). Unlike the MAD alone it sees the heavier tails
    of a mixture (on the sim, runs at 24 threads vary half as much as the others; the MAD of the
    mix was 10–30 % below the standard deviation, and the CUSUM alarmed on that).

    Example:
        >>> round(robust_sd([0.0, 1.0, -1.0, 2.0, -2.0, 50.0]), 2)   # the standard deviation: 18.7
        3.05
    """
    array = np.asarray(list(values), dtype=float)
    deviation = array - float(np.median(array))
    limit = 3 * MAD_TO_SD * float(np.median(np.abs(deviation)))
    return float(np.sqrt(np.mean(np.clip(deviation, -limit, limit) ** 2)))


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
        warmup: runs used to learn the scale (:func:`robust_sd`); when it is learnt they go through
            the sums too, so a change that began during the warm-up counts.
        clip: standardised residuals are clipped to ±clip.
        scale_floor: smallest scale (relative residual), e.g. the sensor's accuracy.
        follow: weight of a new run in the scale after the warm-up (clipped values excluded).
        scale: a known scale instead of a warm-up (None: learn it).
    """

    def __init__(self, group: str, *, k: float = 1.0, h: float = 10.0, warmup: int = 24, clip: float = 3.0,
                 scale_floor: float = 0.002, follow: float = 0.02, scale: float | None = None) -> None:
        self.group = group
        self.k, self.h, self.warmup, self.clip = float(k), float(h), int(warmup), float(clip)
        self.scale_floor, self.follow = float(scale_floor), float(follow)
        self.learning: list[float] = []
        self.scale = math.nan
        if scale is not None:
            self.warmup, self.scale = 0, max(float(scale), self.scale_floor)
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
            if len(self.learning) < self.warmup:
                return None
            # the scale is learnt: the warm-up's own values go through the sums too, so a change
            # that began before the detector could judge it is not given away
            self.scale = max(robust_sd(self.learning), self.scale_floor)
            for value in self.learning:
                self._accumulate(max(-self.clip, min(self.clip, value / self.scale)))
        else:
            z = max(-self.clip, min(self.clip, residual / self.scale))
            self._accumulate(z)
            if abs(z) < self.clip:  # follow slow changes of the scale, not the drift itself
                self.scale = max(self.scale_floor, math.sqrt((1 - self.follow) * self.scale ** 2
                                                             + self.follow * (z * self.scale) ** 2))
        if self.alarmed or max(self.upper, self.lower) <= self.h:
            return None
        self.alarmed = True
        up = self.upper >= self.lower
        return DriftAlarm(self.group, "energy", "residual-cusum", max(self.upper, self.lower), self.h, int(time_ns),
                          "up" if up else "down")

    def _accumulate(self, z: float) -> None:
        self.upper = max(0.0, self.upper + z - self.k)
        self.lower = max(0.0, self.lower - z - self.k)

    def restart(self) -> None:
        """Zero the sums, keep the learnt scale (a sibling's drift was found: what the sums took
        from it while it was still a reference goes)."""
        self.upper = self.lower = 0.0

    def reset(self) -> None:
        """Start again (after a replaced DIMM or a calibration reset; a known scale stays)."""
        self.learning.clear()
        if self.warmup > 0:
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


#: One of a group's currents with its 95 % interval: ``(value, ci_low, ci_high)`` (A).
Current = tuple[float, float, float]


def _log_se(value: float, lo: float, hi: float) -> float:
    """Standard error of ``log(value)`` from a 95 % interval (the wider side; NaN without one)."""
    if not (value > 0 and math.isfinite(lo) and math.isfinite(hi)):
        return math.nan
    return max(hi - value, value - lo) / (1.96 * value)


def sibling_changes(now: Mapping[str, Mapping[str, Current]], reference: Mapping[str, Mapping[str, Current]], *,
                    time_ns: int, tolerance: float = 0.15, z: float = 4.0) -> list[DriftAlarm]:
    """Groups whose currents changed since their reference fit relative to their siblings' changes.

    Args:
        now: group → current → ``(value, ci_low, ci_high)`` of the latest fits (identifiable currents
            not at a bound).
        reference: the same of each group's reference fit.
        time_ns: time put in the alarms.
        tolerance: smallest relative change (vs the siblings' median change) that alarms.
        z: standard errors (of the two fits, log scale) the change must exceed too.

    Returns:
        One alarm per (group, current) whose ``Δ = log(I/I_ref) − median(siblings' log(I/I_ref))``
        (at least two siblings) is beyond both limits; ``statistic`` is ``e^Δ − 1``.

    Example:
        >>> ref = {g: {"idd3n": (0.05, 0.049, 0.051)} for g in ("a", "b", "c")}
        >>> now = {"a": {"idd3n": (0.05, 0.049, 0.051)}, "b": {"idd3n": (0.051, 0.05, 0.052)},
        ...        "c": {"idd3n": (0.062, 0.061, 0.063)}}
        >>> [(a.group, a.direction, round(a.statistic, 2)) for a in sibling_changes(now, ref, time_ns=0)]
        [('c', 'up', 0.22)]
    """
    alarms: list[DriftAlarm] = []
    names = sorted({name for per in now.values() for name in per})
    for name in names:
        change: dict[str, tuple[float, float]] = {}
        for group, per in now.items():
            ref = reference.get(group, {}).get(name)
            if name not in per or ref is None or not (per[name][0] > 0 and ref[0] > 0):
                continue
            se = math.hypot(_log_se(*per[name]), _log_se(*ref))
            change[group] = (math.log(per[name][0] / ref[0]), se)
        for group, (delta_own, se) in change.items():
            others = [v for g, (v, _s) in change.items() if g != group]
            if len(others) < 2:
                continue
            delta = delta_own - float(np.median(others))
            relative = math.expm1(delta)
            if abs(relative) > tolerance and (not math.isfinite(se) or abs(delta) > z * se):
                alarms.append(DriftAlarm(group, name, "sibling", relative, tolerance, int(time_ns),
                                         "up" if delta > 0 else "down"))
    return alarms


def identifiable_currents(fit: Any) -> dict[str, Current]:
    """``{current: (value, ci_low, ci_high)}`` of a :class:`~hdeem_watch.calibrate.result.FitResult`'s
    identifiable currents that are not at a bound (input of :func:`sibling_changes`)."""
    out: dict[str, Current] = {}
    for j, name in enumerate(fit.currents):
        if bool(fit.identifiable[j]) and fit.at_bound[j] is None:
            out[name] = (float(fit.calibrated_a[j]), float(fit.ci95_a[j, 0]), float(fit.ci95_a[j, 1]))
    return out
