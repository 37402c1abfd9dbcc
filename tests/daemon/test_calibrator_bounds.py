"""The daemon's calibrator stays small: it keeps a bounded number of runs (its state is rewritten at every stop)."""

from __future__ import annotations

import pytest

from hdeem_watch.calibrate import run_model as modelling
from hdeem_watch.calibrate.run_model import RunModeller
from hdeem_watch.run_record import RunRecord

MEMSPEC = "samsung-m393a1g43db0-cpb"


def _idle(i: int) -> RunRecord:
    return RunRecord.from_dict({"run_id": f"r{i}", "state": "modelling", "kernel": "idle", "threads": 1, "elements": 0, "repeat": 1, "window_s": 1.0 + i,
            "dram_energy_j": 16.0 * (1.0 + i), "t_stop_ns": i})


def test_the_calibrator_keeps_a_bounded_number_of_runs(monkeypatch: pytest.MonkeyPatch) -> None:
    """Beyond the bound the oldest runs are dropped, also for a state saved with a larger bound."""
    monkeypatch.setattr(modelling, "MAX_CALIBRATION_RUNS", 5)
    m = RunModeller(MEMSPEC, max_requests=100_000)
    for i in range(7):
        m.evaluate(_idle(i))
    assert [o.name.split(":")[0] for o in m.calibrator.observations] == ["r2", "r3", "r4", "r5", "r6"]
    state = m.state()
    assert state is not None
    state["settings"]["max_runs"] = 2000  # saved by an older, unbounded daemon
    monkeypatch.setattr(modelling, "MAX_CALIBRATION_RUNS", 3)
    restored = RunModeller(MEMSPEC, max_requests=100_000, state=state)
    assert restored.calibrator.max_runs == 3
    assert [o.name.split(":")[0] for o in restored.calibrator.observations] == ["r4", "r5", "r6"]
    assert RunModeller(MEMSPEC).calibrator.max_history <= modelling.MAX_CALIBRATOR_HISTORY
