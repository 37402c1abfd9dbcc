"""The batch fit on synthetic rows (no energy model): recovery, bounds, flags, intervals, errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hdeem_watch.calibrate import FitOptions, FitResult, Observation, fit
from hdeem_watch.errors import InputError


def _fit(synth, obs, **kw):
    return fit(obs, synth.spec(), FitOptions(names=synth.NAMES, **kw))


def test_noise_free_rows_give_back_the_hidden_currents_and_intercept(synth, truth_a) -> None:
    """Exact data: every calibrated current and the intercept come back to 1e-6 relative."""
    rng = np.random.default_rng(11)
    obs = synth.observations(rng, synth.kernel_mix(rng, 14), truth_a, offset_j=0.05)
    result = _fit(synth, obs)
    for name, value in result.calibrated.items():
        assert value == pytest.approx(truth_a[name], rel=1e-6)
    assert result.intercept_j == pytest.approx(0.05, rel=1e-5)
    assert result.error_after < 1e-7
    assert result.error_before > 0.5  # the datasheet model overestimates ~2x
    assert result.status == "ok" and result.rank == 6


def test_noisy_rows_with_offset_recover_within_their_intervals(synth, truth_a) -> None:
    """1 % noise and a 2 % per-run offset: each current lies within twice its ci95 half-width of
    the truth, the well-determined ones (half-width ≤ 3 %) within 5 %; the intercept is found;
    errors are ordered after < LOO < before."""
    for seed in range(5):
        rng = np.random.default_rng(100 + seed)
        runs = synth.kernel_mix(rng, 24, idle=4)
        mean_j = np.mean([c @ synth.truth_vector(truth_a) for c, _ in runs])
        obs = synth.observations(rng, runs, truth_a, noise=0.01, offset_j=0.02 * mean_j)
        result = _fit(synth, obs)
        for j, name in enumerate(result.currents):
            lo, hi = result.ci95_a[j]
            half = (hi - lo) / 2
            assert abs(result.calibrated_a[j] - truth_a[name]) <= 2 * half, (seed, name)
            if half <= 0.03 * truth_a[name]:
                assert result.identifiable[j]
                assert result.calibrated_a[j] == pytest.approx(truth_a[name], rel=0.05), (seed, name)
        assert result.intercept_ci95_j[0] <= 0.02 * mean_j <= result.intercept_ci95_j[1] * 1.5
        assert result.error_after < result.error_loo < result.error_before
        assert result.error_loo < 0.02


def test_current_the_runs_do_not_excite_is_flagged_and_left_at_its_prior(synth, truth_a) -> None:
    """Read-only runs never write: IDD4W is flagged unidentifiable, its interval spans its bounds,
    it stays at the datasheet value, the system is reported rank-deficient, the others recover."""
    rng = np.random.default_rng(5)
    runs = synth.kernel_mix(rng, 16, idle=3, writes=False)
    obs = synth.observations(rng, runs, truth_a, noise=0.002)
    result = _fit(synth, obs)
    j = result.currents.index("idd4w")
    assert not result.identifiable[j]
    assert result.sensitivity[j] == 0.0
    assert result.calibrated_a[j] == pytest.approx(synth.DATASHEET["idd4w"], rel=1e-6)
    assert result.status == "rank-deficient" and result.rank == 5
    assert result.to_dict()["observability"]["rank_deficient"] is True
    assert result.to_dict()["observability"]["condition_number"] is None  # infinite
    for name in ("idd0", "idd2n", "idd4r"):
        assert result.identifiable[result.currents.index(name)]
        assert result.calibrated[name] == pytest.approx(truth_a[name], rel=0.03)


def test_refresh_current_makes_the_system_rank_deficient_and_is_flagged(synth, truth_a) -> None:
    """With ρ = 1 and no power-down the columns of all VDD currents add up to the window, and so
    does IDD5B's (refresh every REFI): asked to calibrate IDD5B too, the fit reports the system
    rank-deficient, flags IDD5B, keeps every current within its bounds and still predicts."""
    rng = np.random.default_rng(8)
    obs = synth.observations(rng, synth.kernel_mix(rng, 20, idle=3), truth_a, noise=0.01)
    result = _fit(synth, obs, currents=("idd0", "idd2n", "idd3n", "idd4r", "idd4w", "idd5b"))
    flags = dict(zip(result.currents, result.identifiable))
    assert not flags["idd5b"]
    assert result.status == "rank-deficient" and result.rank == 6
    assert result.singular_values.min() < 1e-9 * result.singular_values.max()
    assert np.all(result.calibrated_a >= 0) and np.all(result.calibrated_a <= result.datasheet_a)
    assert result.error_after < 0.015 and result.error_loo < 0.03


def test_interval_covers_truth_at_its_stated_rate(synth, truth_a) -> None:
    """Over 300 noisy data sets the analytic 95 % interval covers each true current 92–98 % of
    the time (interior truth, 1.5 % noise)."""
    rng = np.random.default_rng(2024)
    runs = synth.kernel_mix(rng, 18, idle=3)
    hits = np.zeros(5)
    trials = 300
    for _ in range(trials):
        obs = synth.observations(rng, runs, truth_a, noise=0.015)
        result = _fit(synth, obs, intercept=False, loo="none")
        truth = np.array([truth_a[n] for n in result.currents])
        hits += (result.ci95_a[:, 0] <= truth) & (truth <= result.ci95_a[:, 1])
    rate = hits / trials
    assert np.all(rate >= 0.92) and np.all(rate <= 0.985), rate
    assert 0.93 <= rate.mean() <= 0.97, rate


def test_bootstrap_interval_also_covers(synth, truth_a) -> None:
    """The residual-bootstrap percentile interval covers the truth at roughly its rate (30 sets)."""
    rng = np.random.default_rng(77)
    runs = synth.kernel_mix(rng, 18, idle=3)
    hits = 0
    total = 0
    for _ in range(30):
        obs = synth.observations(rng, runs, truth_a, noise=0.015)
        result = _fit(synth, obs, intercept=False, loo="none", uncertainty="bootstrap",
                      bootstrap_samples=120, seed=int(rng.integers(1 << 30)))
        assert result.uncertainty.startswith("residual-bootstrap")
        truth = np.array([truth_a[n] for n in result.currents])
        hits += int(np.sum((result.ci95_a[:, 0] <= truth) & (truth <= result.ci95_a[:, 1])))
        total += truth.size
    assert 0.85 <= hits / total <= 1.0


def test_bounds_hold_and_are_configurable(synth, truth_a) -> None:
    """A true current above its datasheet value is clipped at the (default) upper bound and
    reported at_bound; widening the bound recovers it."""
    truth = dict(truth_a, idd4r=synth.DATASHEET["idd4r"] * 1.2)
    rng = np.random.default_rng(3)
    obs = synth.observations(rng, synth.kernel_mix(rng, 16), truth)
    clipped = _fit(synth, obs)
    j = clipped.currents.index("idd4r")
    assert clipped.calibrated_a[j] == pytest.approx(synth.DATASHEET["idd4r"])
    assert clipped.at_bound[j] == "upper"
    assert clipped.ci95_a[j, 1] == pytest.approx(synth.DATASHEET["idd4r"])
    wide = _fit(synth, obs, bounds={"idd4r": (0.0, 0.5)})
    assert wide.calibrated["idd4r"] == pytest.approx(truth["idd4r"], rel=1e-5)
    assert wide.at_bound[j] is None
    with pytest.raises(InputError, match=r"bounds\.idd4r"):
        _fit(synth, obs, bounds={"idd4r": (0.3, 0.1)})
    with pytest.raises(InputError, match="not a calibrated current"):
        _fit(synth, obs, bounds={"idd5b": (0.0, 1.0)})


def test_intercept_can_be_switched_off_and_is_never_negative(synth, truth_a) -> None:
    """intercept=False: one unknown fewer, intercept 0; with it on, a model that overestimates
    every run cannot buy a negative intercept (it stays at 0, at its bound)."""
    rng = np.random.default_rng(4)
    runs = synth.kernel_mix(rng, 12)
    obs = synth.observations(rng, runs, truth_a, noise=0.005)
    off = _fit(synth, obs, intercept=False)
    assert off.intercept_j == 0.0 and not off.intercept_fitted
    assert len(off.singular_values) == 5
    obs_low = [Observation(o.name, o.columns, 0.0, o.measured_j * 0.97 - 0.05) for o in obs]
    on = _fit(synth, obs_low)
    assert on.intercept_j == 0.0
    assert on.intercept_ci95_j[0] == 0.0


def test_prior_pulls_weak_directions_toward_datasheet(synth, truth_a) -> None:
    """Runs that barely write leave IDD4W weakly determined: a mild prior (λ = 0.05) pulls it most
    of the way to its datasheet value and narrows its interval, while the well-determined IDD4R
    moves by less than 1 %."""
    rng = np.random.default_rng(9)
    runs = synth.kernel_mix(rng, 14, idle=2, writes=False)
    runs.append((synth.columns(1e6, 1e8, 2e5, 1.0, 0.6), 1.0))
    obs = synth.observations(rng, runs, truth_a, noise=0.01)
    free = _fit(synth, obs)
    tight = _fit(synth, obs, prior_weight=0.05)
    ds = synth.DATASHEET
    j = free.currents.index("idd4w")
    assert not free.identifiable[j]
    assert abs(tight.calibrated["idd4w"] - ds["idd4w"]) < 0.5 * abs(free.calibrated["idd4w"] - ds["idd4w"])
    assert np.ptp(tight.ci95_a[j]) < np.ptp(free.ci95_a[j])
    assert tight.calibrated["idd4r"] == pytest.approx(free.calibrated["idd4r"], rel=0.01)


def test_loo_hat_identity_matches_exact_refits(synth, truth_a) -> None:
    """With no bound active the hat-matrix leave-one-out equals n explicit refits."""
    rng = np.random.default_rng(12)
    obs = synth.observations(rng, synth.kernel_mix(rng, 15), truth_a, noise=0.01, offset_j=0.1)
    exact = _fit(synth, obs, loo="exact")
    assert all(b is None for b in exact.at_bound) and exact.intercept_j > 0
    hat = _fit(synth, obs, loo="hat")
    assert hat.error_loo == pytest.approx(exact.error_loo, rel=1e-6)
    loo_exact = [r["loo_j"] for r in exact.runs]
    loo_hat = [r["loo_j"] for r in hat.runs]
    assert loo_hat == pytest.approx(loo_exact, rel=1e-7)


def test_weights_scale_rows(synth, truth_a) -> None:
    """A run with weight 0 does not influence the fit (same as leaving it out)."""
    rng = np.random.default_rng(13)
    obs = synth.observations(rng, synth.kernel_mix(rng, 12), truth_a, noise=0.01)
    bad = Observation("bad", obs[3].columns, 0.0, obs[3].measured_j * 3, weight=0.0)
    with_zero = _fit(synth, [*obs, bad], loo="none")
    without = _fit(synth, obs, loo="none")
    assert with_zero.calibrated_a == pytest.approx(without.calibrated_a, rel=1e-8)


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"currents": ("idd0", "idd9x")}, "unknown current 'idd9x'"),
    ({"currents": ()}, "no current"),
    ({"uncertainty": "magic"}, "uncertainty"),
    ({"loo": "sometimes"}, "loo"),
])
def test_bad_settings_are_input_errors(synth, truth_a, kwargs, message) -> None:
    """Unknown currents and modes are one-line InputErrors naming the field."""
    rng = np.random.default_rng(1)
    obs = synth.observations(rng, synth.kernel_mix(rng, 8), truth_a)
    with pytest.raises(InputError, match=message) as info:
        _fit(synth, obs, **kwargs)
    assert "\n" not in str(info.value)


def test_fewer_runs_than_unknowns_is_an_input_error_unless_allowed(synth, truth_a) -> None:
    """5 runs for 6 unknowns: InputError naming the counts; allowed, it is solved and reported
    underdetermined with unknown (NaN → null) intervals."""
    rng = np.random.default_rng(1)
    obs = synth.observations(rng, synth.kernel_mix(rng, 5), truth_a)
    with pytest.raises(InputError, match="5 runs for 6 unknowns"):
        _fit(synth, obs)
    result = _fit(synth, obs, require_overdetermined=False)
    assert result.status == "underdetermined"
    assert np.all(np.isnan(result.ci95_a))
    d = result.to_dict()
    assert d["currents"]["idd0"]["ci95"] == [None, None]
    assert all(0 <= result.calibrated_a[j] <= result.datasheet_a[j] for j in range(5))


@pytest.mark.parametrize("measured", [0.0, -1.0, float("nan"), float("inf"), "3", True, None])
def test_bad_measured_energy_names_the_run(measured) -> None:
    """measured_j ≤ 0 or not a number is an InputError naming the run and the field."""
    with pytest.raises(InputError, match=r"run 'triad': measured_j"):
        Observation("triad", np.ones(3), 0.0, measured)  # type: ignore[arg-type]


def test_to_dict_is_the_json_contract_and_round_trips(synth, truth_a) -> None:
    """to_dict has currents.<name>.{datasheet, calibrated, ci95, identifiable}, intercept_j,
    error.{before, after, loo}, observability.{condition_number, singular_values}; it is valid
    JSON (no NaN/Infinity) and from_dict gives the same reported values back."""
    rng = np.random.default_rng(21)
    obs = synth.observations(rng, synth.kernel_mix(rng, 12, writes=False), truth_a, noise=0.01)
    result = _fit(synth, obs)
    data = json.loads(json.dumps(result.to_dict(), allow_nan=False))
    for name in result.currents:
        assert set(data["currents"][name]) >= {"datasheet", "calibrated", "ci95", "identifiable"}
    assert set(data["error"]) == {"before", "after", "loo"}
    assert set(data["observability"]) >= {"condition_number", "singular_values"}
    assert isinstance(data["intercept_j"], float)
    back = FitResult.from_dict(data)
    assert back.to_dict() == data
