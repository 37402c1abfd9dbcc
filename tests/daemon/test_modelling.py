"""The daemon's run model: the node's traffic split, predictions from the fit before the run, suggestions."""

from __future__ import annotations

import numpy as np
import pytest

from hdeem_watch.calibrate.run_model import RunModeller
from hdeem_watch.run_record import RunRecord

MEMSPEC = "samsung-m393a1g43db0-cpb"
ELEMENTS = 1 << 22


def _record(i: int, kernel: str, threads: int, window_s: float, energy_j: float) -> RunRecord:
    return RunRecord.from_dict({"run_id": f"r{i}", "state": "modelling", "kernel": kernel, "threads": threads, "elements": 0 if kernel == "idle" else ELEMENTS,
            "repeat": 4, "window_s": window_s, "dram_energy_j": energy_j, "t_stop_ns": i})


def test_row_is_the_sum_of_the_socket_groups() -> None:
    """6 threads load socket 0's 4 DIMMs only: the row is 4 × a loaded DIMM + 4 × an idle DIMM, not 8 × 1/8."""
    from hdeem_watch.calibrate import Observation, observation_from_run
    from hdeem_watch.dram.node import idle_channel_stats, node_run_stats

    m = RunModeller(MEMSPEC, dimms=8, max_requests=100_000)
    model, _fit, error = m.evaluate(_record(0, "copy", 6, 0.5, 10.0))
    assert error is None and model is not None
    row = Observation.from_dict(model["observation"])
    groups = node_run_stats(m.spec, "copy", ELEMENTS, 6, 4, max_requests=100_000)
    assert groups[1][0] == idle_channel_stats(m.spec) and [n for _s, n in groups] == [4, 4]
    loaded = observation_from_run(m.spec, groups[0][0], 0.5, 10.0, scale=4)
    idle = observation_from_run(m.spec, groups[1][0], 0.5, 10.0, scale=4)
    assert np.allclose(row.columns, loaded.columns + idle.columns)
    assert row.constant_j == pytest.approx(loaded.constant_j + idle.constant_j)
    assert model["counts"]["rd"] == pytest.approx(4 * groups[0][0].total("rd"))


def test_calibrated_energy_is_a_prediction_from_the_fit_before_the_run() -> None:
    """A run's calibrated model energy uses the fit of the earlier runs (none for the first); fitted_j is after."""
    m = RunModeller(MEMSPEC, dimms=8, max_requests=100_000)
    runs = [("idle", 24, 1.0, 9.0), ("read", 24, 0.6, 9.5), ("copy", 4, 1.2, 12.0), ("triad", 12, 0.8, 8.5)]
    before = None
    for i, (kernel, threads, window, energy) in enumerate(runs):
        model, fit, error = m.evaluate(_record(i, kernel, threads, window, energy))
        assert error is None and model is not None and fit is not None
        if before is None:
            assert model["calibrated_j"] is None
        else:
            vec, intercept = m._currents_vector(before)
            from hdeem_watch.calibrate import Observation

            expected = Observation.from_dict(model["observation"]).predicted_j(vec, intercept)
            assert model["calibrated_j"] == pytest.approx(expected)
            assert model["calibrated_j"] == model["predicted_j"]
        assert model["fitted_j"] is not None
        before = fit
    # the last run was fitted with itself: its fitted energy is closer to the measurement than the prediction
    assert abs(model["fitted_j"] - 8.5) <= abs(model["calibrated_j"] - 8.5)


def test_calib_body_suggests_the_next_run() -> None:
    """After a fit the calib body ranks the kinds of runs seen (and idle) by what one more would determine."""
    m = RunModeller(MEMSPEC, dimms=8, max_requests=100_000)
    assert m.body()["suggest"] is None
    for i, (kernel, threads, window, energy) in enumerate(
            [("idle", 24, 1.0, 9.0), ("read", 24, 0.6, 9.5), ("copy", 4, 1.2, 12.0), ("idle", 24, 2.0, 18.0)]):
        m.evaluate(_record(i, kernel, threads, window, energy))
    suggest = m.body()["suggest"]
    assert suggest and all(isinstance(name, str) and 0.0 <= score <= 1.0 for name, score in suggest)
    assert {name for name, _ in suggest} <= {"idle", "read-24t", "copy-4t"}
    scores = [score for _name, score in suggest]
    assert scores == sorted(scores, reverse=True)
