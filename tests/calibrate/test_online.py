"""The online calibrator: refit per run, half-life forgetting, drift flags, persistence."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hdeem_watch.calibrate import Observation, OnlineCalibrator, suggest_next
from hdeem_watch.errors import InputError

DAY_NS = 86_400 * 10**9


def _aging_stream(synth, truth_a, *, days: int, per_day: int, seed: int):
    """Runs every 24/per_day hours from a rotating mix; IDD3N falls 30 % and IDD0 rises 10 %
    linearly over ``days`` (aging); yields (observation, true currents at that time)."""
    rng = np.random.default_rng(seed)
    mix = synth.kernel_mix(rng, 24, idle=4)
    for i in range(days * per_day):
        t_ns = i * DAY_NS // per_day
        age = t_ns / (days * DAY_NS)
        truth = dict(truth_a, idd3n=truth_a["idd3n"] * (1 - 0.3 * age), idd0=truth_a["idd0"] * (1 + 0.1 * age))
        cols, seconds = mix[i % len(mix)]
        energy = cols @ synth.truth_vector(truth)
        obs = Observation(f"run{i}", cols, 0.0, float(energy * (1 + 0.005 * rng.standard_normal())),
                          time_ns=t_ns, window_s=seconds)
        yield obs, truth


def test_half_life_follows_aging_and_flags_drift(synth, truth_a) -> None:
    """IDD3N ages by −30 % over 60 days: with a 2-day half-life the latest fit is within 3 % of
    the current truth and drift() flags IDD3N (not IDD4R, which does not change); never
    forgetting lags behind by more than 8 % and is no closer."""
    spec = synth.spec()
    forgetful = OnlineCalibrator(spec, names=synth.NAMES, half_life_s=2 * 86400.0)
    forever = OnlineCalibrator(spec, names=synth.NAMES, half_life_s=None)
    truth = truth_a
    for obs, truth_then in _aging_stream(synth, truth_a, days=60, per_day=4, seed=1):
        forgetful.add_run(obs)
        forever.add_run(obs)
        truth = truth_then
    now = forgetful.latest
    assert now is not None and forever.latest is not None
    assert now.calibrated["idd3n"] == pytest.approx(truth["idd3n"], rel=0.03)
    assert now.calibrated["idd4r"] == pytest.approx(truth["idd4r"], rel=0.03)
    lag = abs(forever.latest.calibrated["idd3n"] / truth["idd3n"] - 1)
    assert lag > 0.08
    assert abs(now.calibrated["idd3n"] / truth["idd3n"] - 1) < lag
    flags = forgetful.drift()
    assert flags["idd3n"] is True
    assert flags["idd4r"] is False
    assert forever.drift() == dict.fromkeys(forever.currents, False)  # no half-life, no lag: no reference
    # Old runs are forgotten: 12 half-lives ago weighs 2^-12 < min_weight 1e-4... none that old kept.
    ages = [(now.time_ns - o.time_ns) / DAY_NS for o in forgetful.observations]
    assert max(ages) < 2 * np.log2(1e4) + 1
    assert len(forever.observations) == 240


def test_history_is_time_stamped_and_bounded(synth, truth_a) -> None:
    """Each add_run appends (time_ns, fit) in time order; max_history keeps the newest."""
    calib = OnlineCalibrator(synth.spec(), names=synth.NAMES, max_history=10)
    stream = _aging_stream(synth, truth_a, days=4, per_day=6, seed=2)
    for obs, _truth in stream:
        result = calib.add_run(obs)
        assert calib.latest is result
        assert calib.history[-1] == (obs.time_ns, result)
    assert len(calib.history) == 10
    times = [t for t, _ in calib.history]
    assert times == sorted(times)


def test_first_runs_are_underdetermined_not_errors(synth, truth_a) -> None:
    """With fewer runs than unknowns the calibrator still answers (status 'underdetermined',
    currents within bounds, unknown intervals), then becomes 'ok'."""
    calib = OnlineCalibrator(synth.spec(), names=synth.NAMES)
    stream = _aging_stream(synth, truth_a, days=2, per_day=12, seed=3)
    first = calib.add_run(next(stream)[0])
    assert first.status == "underdetermined"
    assert np.all(first.calibrated_a <= first.datasheet_a) and np.all(first.calibrated_a >= 0)
    for obs, _ in stream:
        last = calib.add_run(obs)
    assert last.status == "ok"


def test_state_round_trips_through_json(synth, truth_a) -> None:
    """to_dict → JSON → from_dict restores runs, settings and history; the restored latest fit
    equals the original, and adding the same next run to both gives the same fit."""
    calib = OnlineCalibrator(synth.spec(), names=synth.NAMES, half_life_s=3 * 86400.0,
                             bounds={"idd4r": (0.0, 0.3)}, prior_weight=0.01)
    stream = list(_aging_stream(synth, truth_a, days=5, per_day=6, seed=4))
    for obs, _ in stream[:-1]:
        calib.add_run(obs)
    text = json.dumps(calib.to_dict(), allow_nan=False)
    back = OnlineCalibrator.from_dict(json.loads(text), synth.spec())
    assert back.latest is not None and calib.latest is not None
    assert back.latest.calibrated_a == pytest.approx(calib.latest.calibrated_a, rel=1e-12)
    assert len(back.history) == len(calib.history)
    assert back.history[0][1].to_dict()["currents"] == calib.history[0][1].to_dict()["currents"]
    a = calib.add_run(stream[-1][0])
    b = back.add_run(stream[-1][0])
    assert a.calibrated_a == pytest.approx(b.calibrated_a, rel=1e-12)
    assert suggest_next(back, {"obs": stream[0][0]})[0][0] == "obs"
    with pytest.raises(InputError, match="version"):
        OnlineCalibrator.from_dict({"version": 99}, synth.spec())


def test_reset_forgets_everything(synth, truth_a) -> None:
    """reset() drops runs, history and the latest fit."""
    calib = OnlineCalibrator(synth.spec(), names=synth.NAMES)
    for obs, _ in _aging_stream(synth, truth_a, days=1, per_day=8, seed=5):
        calib.add_run(obs)
    calib.reset()
    assert calib.latest is None and calib.history == [] and calib.observations == []
    with pytest.raises(InputError, match="no fit yet"):
        suggest_next(calib, {"x": Observation("x", np.ones(len(synth.NAMES)), 0.0, 1.0)})


def test_row_of_the_wrong_width_is_rejected(synth) -> None:
    """A row with a different number of model columns is an InputError naming the run."""
    calib = OnlineCalibrator(synth.spec(), names=synth.NAMES)
    with pytest.raises(InputError, match="run 'short'"):
        calib.add_run(Observation("short", np.ones(3), 0.0, 1.0))


def test_max_runs_keeps_the_newest(synth, truth_a) -> None:
    """Without a half-life, max_runs bounds the kept runs, dropping the oldest."""
    calib = OnlineCalibrator(synth.spec(), names=synth.NAMES, half_life_s=None, max_runs=20)
    for obs, _ in _aging_stream(synth, truth_a, days=3, per_day=10, seed=6):
        calib.add_run(obs)
    assert len(calib.observations) == 20
    assert [o.name for o in calib.observations] == [f"run{i}" for i in range(10, 30)]


def test_a_trusted_calibrator_refreshes_its_intervals_every_eight_runs_after_64() -> None:
    """The full trusted intervals (a jackknife and mapping refits: tens of fits) are computed at every
    refit of a young fit, then every 8th run; in between the central fit carries the last ones, with
    the same values as a full refit would give."""
    from hdeem_watch.calibrate.trust import TrustOptions, trusted_fit

    class Spec:
        def __init__(self) -> None:
            self.currents = {"a": 1.0, "b": 1.0}

    calib = OnlineCalibrator(Spec(), currents=("a", "b"), names=("a", "b"), half_life_s=None, intercept=False,
                             trust=TrustOptions())
    rng = np.random.default_rng(3)
    refreshed = []
    for i in range(90):
        x = float(rng.uniform(1, 3))
        result = calib.add_run(Observation(f"r{i}:k{i % 6}", np.array([x, 1.0]), 0.0,
                                           0.5 * x + 0.8 + 0.005 * rng.normal(), time_ns=i))
        refreshed.append((result.trust or {}).get("refreshed_runs"))
    assert refreshed[:64] == [None] * 64
    assert [i + 1 for i, r in enumerate(refreshed) if r is None][64:] == [72, 80, 88]
    assert refreshed[-1] == 88
    full = trusted_fit(calib.observations, Spec(), calib.fit_options(), trust=TrustOptions())
    assert np.allclose(calib.latest.calibrated_a, full.calibrated_a)
    assert np.allclose(calib.latest.ci95_a, full.ci95_a, rtol=0.05)
