"""The drift detector and the sibling comparison (calibrate/drift.py) on controlled input."""

from __future__ import annotations

import numpy as np
import pytest

from hdeem_watch.calibrate.drift import (
    ResidualCusum,
    arl0_two_sided,
    robust_sd,
    sibling_changes,
    sibling_residuals,
)


def _run_length(rng: np.random.Generator, h: float, shift: float = 0.0, limit: int = 100_000, k: float = 0.5) -> int:
    det = ResidualCusum("g", h=h, k=k, clip=4.0, scale=1.0, follow=0.0)
    for i in range(limit):
        if det.update(float(rng.standard_normal()) + shift, i) is not None:
            return i + 1
    return limit


def test_in_control_run_length_matches_siegmund() -> None:
    """On i.i.d. N(0, 1) residuals the mean run length to a false alarm is the stated ARL0 (k = 0.5,
    h = 4: ≈ 169 runs) within 25 % — the figure the false-alarm rate is derived from."""
    rng = np.random.default_rng(1)
    lengths = [_run_length(rng, 4.0) for _ in range(400)]
    assert np.mean(lengths) == pytest.approx(arl0_two_sided(0.5, 4.0), rel=0.25)


def test_false_alarm_rate_at_the_defaults_on_noise() -> None:
    """At the defaults (k = 1, h = 10, clip 3, scale learnt over 24 values) the stated ARL₀ is
    ≈ 1.2·10⁹ runs; 200 streams of 800 runs of i.i.d. N(0, 1) — each the demo's 2 sim-hours — raise
    no alarm (the stated rate predicts 10⁻⁴ in all of them; the scale learnt from 24 values makes it
    larger), and neither do 200 streams of
    Student-t(5) noise (heavier tails, as the sim's residuals; the clip bounds them)."""
    assert arl0_two_sided(1.0, 8.0) > 2e7
    rng = np.random.default_rng(7)
    for draw in (lambda n: rng.standard_normal(n), lambda n: rng.standard_t(5, n)):
        alarms = 0
        for _ in range(200):
            det = ResidualCusum("g")
            alarms += sum(det.update(float(v) * 0.01, i) is not None for i, v in enumerate(draw(824)))
        assert alarms == 0


def test_a_ramp_is_found_within_the_stated_delay() -> None:
    """A ramp that adds 0.1 scale units per run from run 100 on (e.g. +30 %/h seen through
    same-kind changes) is found at the defaults ≈ 24 runs after its start in each of 50 streams
    (without noise the CUSUM crosses 10 once Σ(δ_t − k) > 10: δ passes k = 1 at run 10, the sum
    reaches 10 fourteen runs later), and never before it starts."""
    rng = np.random.default_rng(3)
    delays = []
    for _ in range(50):
        det = ResidualCusum("g")
        for i in range(400):
            ramp = 0.1 * max(0, i - 100)
            if det.update(float(rng.standard_normal() + ramp), i) is not None:
                delays.append(i - 100)
                break
    assert len(delays) == 50 and min(delays) > 10 and max(delays) <= 34, delays
    assert np.median(delays) == pytest.approx(24, abs=3)


def test_robust_sd_sees_the_spread_of_a_mixture() -> None:
    """The scale is the spread of a 1:3 mixture of sd 0.5 and 1 (sd 0.90) within 10 %, where the
    MAD alone says ~0.8; one wild value moves it little."""
    rng = np.random.default_rng(4)
    values = np.concatenate([0.5 * rng.standard_normal(2500), rng.standard_normal(7500)])
    assert robust_sd(values) == pytest.approx(np.sqrt(0.25 * 0.25 + 0.75), rel=0.1)
    assert robust_sd([*values[:23], 1e6]) < 2.0


def test_a_step_is_found_in_the_stated_delay() -> None:
    """A step of 2 scale units is detected in ≈ (h + 1.166)/(δ − k) runs (h = 12: ≈ 9)."""
    rng = np.random.default_rng(2)
    delays = [_run_length(rng, 12.0, shift=2.0) for _ in range(100)]
    assert np.median(delays) == pytest.approx((12 + 1.166) / (2 - 0.5), rel=0.3)


def test_one_wild_run_does_not_alarm_and_reset_restarts() -> None:
    """A single residual of 100 scales adds at most clip − k (2) to the CUSUM: no alarm at h = 10;
    after an alarm no second one until reset."""
    det = ResidualCusum("g", warmup=3)
    for i, d in enumerate([0.01, -0.01, 0.005]):
        det.update(d, i)
    assert det.update(1.0, 10) is None and det.upper <= 2.0 + 1e-9
    alarms = [det.update(0.2, 20 + i) for i in range(10)]
    assert sum(a is not None for a in alarms) == 1
    det.reset()
    assert det.upper == 0.0 and det.learning == []


def test_siblings() -> None:
    """Residuals are taken against the siblings' median (as is with fewer than two siblings)."""
    assert sibling_residuals({"a": 0.1, "b": 0.0})["a"] == 0.1
    assert sibling_residuals({"a": 0.1, "b": 0.0, "c": 0.02, "d": float("nan")})["a"] == pytest.approx(0.09)
    # a drifting group is no sibling: "a" against the median of b and c (0.01), not of b, c, d (0.02)
    drifting = {"a": 0.0, "b": 0.0, "c": 0.02, "d": 0.3}
    assert sibling_residuals(drifting)["a"] == pytest.approx(-0.02)
    assert sibling_residuals(drifting, exclude={"d"})["a"] == pytest.approx(-0.01)
    assert sibling_residuals(drifting, exclude={"d"})["d"] == pytest.approx(0.3)


def test_sibling_changes_compare_each_pair_with_its_own_reference() -> None:
    """Levels that differ by 40 % (parts, offsets) raise nothing while they keep their ratios; a pair
    whose current grew 30 % since its reference while its siblings' grew 2 % is named, once per
    current; a change within the tolerance or within z standard errors is not."""
    ref = {"AB": {"idd3n": (0.050, 0.049, 0.051)}, "CD": {"idd3n": (0.052, 0.051, 0.053)},
           "EF": {"idd3n": (0.049, 0.048, 0.050)}, "GH": {"idd3n": (0.070, 0.069, 0.071)}}
    assert sibling_changes(ref, ref, time_ns=1) == []
    now = {g: {"idd3n": tuple(v * 1.02 for v in per["idd3n"])} for g, per in ref.items()}
    now["CD"] = {"idd3n": (0.052 * 1.3, 0.052 * 1.3 - 0.001, 0.052 * 1.3 + 0.001)}
    alarms = sibling_changes(now, ref, time_ns=5)
    assert [(a.group, a.current, a.direction, a.kind) for a in alarms] == [("CD", "idd3n", "up", "sibling")]
    assert alarms[0].statistic == pytest.approx(1.3 / 1.02 - 1, rel=1e-6)
    now["CD"] = {"idd3n": (0.052 * 1.1, 0.052 * 1.1 - 0.001, 0.052 * 1.1 + 0.001)}  # within 15 %
    assert sibling_changes(now, ref, time_ns=5) == []
    now["CD"] = {"idd3n": (0.052 * 1.3, 0.052, 0.052 * 1.6)}  # +30 % but an interval of ±15 %: < 4 se
    assert sibling_changes(now, ref, time_ns=5) == []


def test_restart_zeroes_the_sums_and_keeps_the_scale() -> None:
    det = ResidualCusum("DDR_GH", warmup=3, h=10.0)
    for t, d in enumerate([0.01, -0.01, 0.0, -0.03, -0.03]):
        det.update(d, t)
    scale, lower = det.scale, det.lower
    assert lower > 0 and scale > 0
    det.restart()
    assert det.lower == det.upper == 0.0 and det.scale == scale and not det.alarmed
