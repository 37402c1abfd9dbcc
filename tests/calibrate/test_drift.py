"""The drift detector and the sibling comparison (calibrate/drift.py) on controlled input."""

from __future__ import annotations

import numpy as np
import pytest

from hdeem_watch.calibrate.drift import ResidualCusum, arl0_two_sided, sibling_outliers, sibling_residuals


def _run_length(rng: np.random.Generator, h: float, shift: float = 0.0, limit: int = 100_000) -> int:
    det = ResidualCusum("g", h=h, warmup=50)
    for i in range(50):
        det.update(float(rng.standard_normal()), i)
    for i in range(limit):
        if det.update(float(rng.standard_normal()) + shift, 50 + i) is not None:
            return i + 1
    return limit


def test_in_control_run_length_matches_siegmund() -> None:
    """On i.i.d. N(0, 1) residuals the mean run length to a false alarm is the stated ARL0 (k = 0.5,
    h = 4: ≈ 169 runs) within 25 % — the figure the false-alarm rate is derived from."""
    rng = np.random.default_rng(1)
    lengths = [_run_length(rng, 4.0) for _ in range(400)]
    assert np.mean(lengths) == pytest.approx(arl0_two_sided(0.5, 4.0), rel=0.25)


def test_a_step_is_found_in_the_stated_delay() -> None:
    """A step of 2 scale units is detected in ≈ (h + 1.166)/(δ − k) runs (h = 12: ≈ 9)."""
    rng = np.random.default_rng(2)
    delays = [_run_length(rng, 12.0, shift=2.0) for _ in range(100)]
    assert np.median(delays) == pytest.approx((12 + 1.166) / (2 - 0.5), rel=0.3)


def test_one_wild_run_does_not_alarm_and_reset_restarts() -> None:
    """A single residual of 100 scales adds at most clip − k (3.5) to the CUSUM: no alarm at h = 12;
    after an alarm no second one until reset."""
    det = ResidualCusum("g", warmup=3)
    for i, d in enumerate([0.01, -0.01, 0.005]):
        det.update(d, i)
    assert det.update(1.0, 10) is None and det.upper <= 3.5 + 1e-9
    alarms = [det.update(0.2, 20 + i) for i in range(10)]
    assert sum(a is not None for a in alarms) == 1
    det.reset()
    assert det.upper == 0.0 and det.learning == []


def test_siblings() -> None:
    """Residuals are taken against the siblings' median (as is with fewer than two siblings);
    a current 40 % above its siblings with an interval clear of theirs is an outlier, one within
    the tolerance or overlapping them is not."""
    assert sibling_residuals({"a": 0.1, "b": 0.0})["a"] == 0.1
    assert sibling_residuals({"a": 0.1, "b": 0.0, "c": 0.02, "d": float("nan")})["a"] == pytest.approx(0.09)
    # a drifting group is no sibling: "a" against the median of b and c (0.01), not of b, c, d (0.02)
    drifting = {"a": 0.0, "b": 0.0, "c": 0.02, "d": 0.3}
    assert sibling_residuals(drifting)["a"] == pytest.approx(-0.02)
    assert sibling_residuals(drifting, exclude={"d"})["a"] == pytest.approx(-0.01)
    assert sibling_residuals(drifting, exclude={"d"})["d"] == pytest.approx(0.3)
    fits = {"AB": {"idd3n": (0.050, 0.048, 0.052)}, "CD": {"idd3n": (0.052, 0.050, 0.054)},
            "EF": {"idd3n": (0.049, 0.047, 0.051)}, "GH": {"idd3n": (0.071, 0.069, 0.073)}}
    alarms = sibling_outliers(fits, time_ns=5)
    assert [(a.group, a.current, a.direction) for a in alarms] == [("GH", "idd3n", "up")]
    fits["GH"] = {"idd3n": (0.071, 0.050, 0.09)}  # interval reaches the siblings: no alarm
    assert sibling_outliers(fits, time_ns=5) == []


def test_restart_zeroes_the_sums_and_keeps_the_scale() -> None:
    det = ResidualCusum("DDR_GH", warmup=3, h=10.0)
    for t, d in enumerate([0.01, -0.01, 0.0, -0.03, -0.03]):
        det.update(d, t)
    scale, lower = det.scale, det.lower
    assert lower > 0 and scale > 0
    det.restart()
    assert det.lower == det.upper == 0.0 and det.scale == scale and not det.alarmed
