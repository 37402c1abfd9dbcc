"""Calibrated currents against the simulated node's truth (issue #32), on one seed each: with the sim's
memory-controller counters every row comes from the counted commands and IDD0/IDD4R/IDD4W come back
determined and right; without them the currents that rest on modelled activations are not called
determined, and their intervals cover the truth. The many-seed figures are ``benchmarks/bench_trust.py``'s.
Truth is the sim's own analytic mapping of its hidden currents (``counted_currents_a`` /
``effective_currents_a``), never a fit."""

from __future__ import annotations

from typing import Any

import pytest

from hdeem_watch.calibrate import FitOptions, fit
from hdeem_watch.calibrate.trust import TrustOptions
from hdeem_watch.demo.sim_runs import DEMO_TAIL_S, SimRuns

# One worker runs the module, so its module-scoped fixture is built once, not once per worker.
#: A long end-to-end accuracy check (two fits of 110 sim runs, ~16 s of CPU): in the full run only.
pytestmark = [pytest.mark.xdist_group("demo-trust_sim"), pytest.mark.slow]

RUNS = 110


def _fitted(counters: bool, seed: int) -> tuple[SimRuns, list[Any]]:
    sim = SimRuns(seed, counters=counters, groups=False, holdout=True, tail_s=DEMO_TAIL_S)
    sim.modeller.calibrator.trust = TrustOptions(jackknife=False, draws=0)  # the full intervals at the end
    done = [sim.step() for _ in range(RUNS)]
    sim.modeller.calibrator.trust = TrustOptions()
    sim.modeller.calibrator.refit()
    return sim, done


@pytest.fixture(scope="module")
def counted() -> tuple[SimRuns, list[Any]]:
    return _fitted(True, 2)


@pytest.fixture(scope="module")
def modelled() -> tuple[SimRuns, list[Any]]:
    return _fitted(False, 2)


def test_counted_rows_come_from_the_counters_and_match_the_kernels_traffic(counted) -> None:
    """Every kernel run's row is built from its counted window: the counted reads equal the kernel's
    (the window is cut exactly), activations differ (the sim's mapping is not the model's)."""
    sim, done = counted
    kernel_runs = [d for d in done if d.record["kernel"] != "idle" and d.model is not None]
    assert kernel_runs and all(d.model["source"] == "counters" for d in kernel_runs)
    ratios = [d.model["kernel_model"]["ratio"] for d in kernel_runs]
    assert all(r["rd"] == pytest.approx(1.0, abs=1e-3) for r in ratios)
    assert max(abs(r["act"] - 1.0) for r in ratios if r["act"]) > 0.3
    assert {o.commands for o in sim.modeller.calibrator.observations} == {"counters"}
    assert sim.modeller.latest_fit()["trust"]["commands"] == "counted"


def test_with_counters_idd0_idd4r_idd4w_are_determined_within_ten_percent(counted) -> None:
    sim, _done = counted
    fit_now = sim.modeller.latest_fit()
    truth = sim.sim.truth()["counted_currents_a"]
    for name in ("idd0", "idd3n", "idd4r", "idd4w"):
        entry = fit_now["currents"][name]
        assert entry["identifiable"], name
        assert entry["calibrated"] == pytest.approx(truth[name], rel=0.10), name
        low, high = entry["ci95"]
        assert low <= truth[name] <= high, name


def test_without_a_state_of_its_own_idd2n_is_held_and_not_called_determined(counted) -> None:
    """With counters and power-down, no window shows precharged standby: IDD2N is held at its
    datasheet value scaled like IDD3N, its range carried into IDD0's interval."""
    sim, _done = counted
    fit_now = sim.modeller.latest_fit()
    held = fit_now["trust"]["held"]["idd2n"]
    cur = fit_now["currents"]
    assert not cur["idd2n"]["identifiable"] and held["anchor"] == "idd3n"
    expected = cur["idd2n"]["datasheet"] * cur["idd3n"]["calibrated"] / cur["idd3n"]["datasheet"]
    assert cur["idd2n"]["calibrated"] == pytest.approx(expected, rel=0.02)
    assert cur["idd2n"]["ci95"] == pytest.approx(held["range"])


def test_hold_out_runs_are_predicted_never_fitted_and_within_ten_percent(counted) -> None:
    sim, done = counted
    holdout = [d for d in done if (d.record.get("metadata") or {}).get("holdout")]
    assert holdout and all(d.error and "hold-out" in d.error for d in holdout)
    names = {o.name for o in sim.modeller.calibrator.observations}
    assert not any(f"{d.record['run_id']}:" in n for d in holdout for n in names)
    errors = [abs(d.model["calibrated_j"] / d.record["dram_energy_j"] - 1) for d in holdout]
    assert max(errors) <= 0.10, errors


def test_without_counters_what_rests_on_modelled_activations_is_not_determined(modelled) -> None:
    """The plain fit of the same rows calls IDD0 and IDD4R determined and is far off; the fit the
    daemon shows does not call them determined and its intervals cover the truth."""
    sim, _done = modelled
    truth = sim.sim.truth()["effective_currents_a"]
    calibrator = sim.modeller.calibrator
    plain = fit(calibrator.observations, calibrator.spec, FitOptions(currents=calibrator.currents, loo="none")).to_dict()
    assert plain["currents"]["idd4r"]["identifiable"]
    assert abs(plain["currents"]["idd4r"]["calibrated"] / truth["idd4r"] - 1) > 0.25
    shown = sim.modeller.latest_fit()
    assert shown["trust"]["commands"] == "modelled"
    for name, entry in shown["currents"].items():
        if entry["identifiable"]:
            assert entry["calibrated"] == pytest.approx(truth[name], rel=0.15), name
        low, high = entry["ci95"]
        assert low <= truth[name] <= high, name
    assert not shown["currents"]["idd0"]["identifiable"] and not shown["currents"]["idd4r"]["identifiable"]
    assert {"idd0", "idd4r"} <= set(shown["trust"]["unconfirmed"])
