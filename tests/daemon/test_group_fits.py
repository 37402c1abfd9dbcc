"""The run modeller's per-sensor-group fits: groups from the source, the guard rail (a run too short to
measure is recorded, not fitted, and says why), one fit per group beside the node fit, their state,
a reset of one group."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest

from hdeem_watch.calibrate.group_fits import default_groups, source_groups
from hdeem_watch.calibrate.group_rows import SensorGroup, group_observation
from hdeem_watch.calibrate.observation import current_names
from hdeem_watch.calibrate.run_model import RunModeller
from hdeem_watch.errors import InputError
from hdeem_watch.run_record import RunRecord
from hdeem_watch.sim.layout import TAURUS, SimLayout

MEMSPEC = "samsung-m393a1g43db0-cpb"
RATES = {"DDR_AB": 100.0, "DDR_CD": 100.0, "DDR_EF": 100.0, "DDR_GH": 100.0}
GROUPS = default_groups(RATES, 2, 4)
#: Each pair's parts draw this much more than the datasheet (a different part per pair).
PART = {"DDR_AB": 1.0, "DDR_CD": 1.12, "DDR_EF": 0.95, "DDR_GH": 1.04}
SCHEDULE = [("idle", 1), ("read", 4), ("triad", 24), ("copy", 12), ("read", 24), ("assign", 6), ("idle", 1),
            ("add", 18), ("scale", 8), ("triad", 6), ("copy", 24), ("read", 12), ("idle", 1), ("add", 4)]


class _Layout:
    """A source that has a layout (as the simulated node does)."""

    layout = SimLayout.regular(1, 8, 6)


def test_groups_come_from_the_sim_layout_else_the_taurus_mapping() -> None:
    assert [(g.name, g.dimms_per_socket) for g in GROUPS] == [("DDR_AB", (2, 0)), ("DDR_CD", (2, 0)),
                                                               ("DDR_EF", (0, 2)), ("DDR_GH", (0, 2))]
    rapl = default_groups({"DRAM0": 1000.0, "DRAM1": 1000.0, "DRAM7": 1000.0}, 2, 4)
    assert [(g.name, g.dimms_per_socket) for g in rapl] == [("DRAM0", (4, 0)), ("DRAM1", (0, 4))]
    one_socket = source_groups(_Layout(), {}, sockets=2, dimms_per_socket=4)
    assert [(g.name, g.dimms_per_socket) for g in one_socket] == [("DDR_AB", (2,)), ("DDR_CD", (2,)), ("DDR_EF", (2,))]

    class Taurus:
        layout = TAURUS

    assert source_groups(Taurus(), {}, sockets=2, dimms_per_socket=4) == tuple(GROUPS)


def _energies(m: RunModeller, record: dict[str, Any]) -> dict[str, float]:
    """Each pair's energy: its row with the datasheet currents times its part factor."""
    stats = m.groups_for(record["kernel"], record["elements"], record["threads"], record["repeat"])
    names = current_names()
    vec = np.array([float(m.spec.currents.get(n, 0.0)) for n in names])
    out = {}
    for group in GROUPS:
        row = group_observation(m.spec, stats, group, record["window_s"], 1.0)
        out[group.name] = PART[group.name] * row.predicted_j(vec)
    return out


def _record(m: RunModeller, i: int, kernel: str, threads: int, window_s: float = 5.0) -> dict[str, Any]:
    record: dict[str, Any] = {"run_id": f"r{i}", "name": kernel, "kernel": kernel, "threads": threads,
                              "elements": 0 if kernel == "idle" else 1 << 22, "repeat": 4, "window_s": window_s,
                              "t_stop_ns": (i + 1) * 10**9}
    record["energy_j"] = _energies(m, record)
    record["dram_energy_j"] = sum(record["energy_j"].values())
    return RunRecord.from_dict({"state": "modelling", **record})


def _modeller(**kwargs: Any) -> RunModeller:
    return RunModeller(MEMSPEC, max_requests=100_000, groups=GROUPS, dram_rates_hz=RATES, **kwargs)


def test_a_10ms_run_is_recorded_not_fitted_and_says_why() -> None:
    m = _modeller()
    model, fit, error = m.evaluate(_record(m, 0, "triad", 24, window_s=0.01))
    assert fit is None and model is not None and model["datasheet_j"] > 0
    assert error is not None and "1 samples of DDR_AB in 0.01 s" in error and "at least 100" in error
    body = m.body()
    assert body["runs"] == 0 and all(g["runs"] == 0 for g in body["groups"].values())
    # 1 s at 100 Sa/s is enough
    _model, fit, error = m.evaluate(_record(m, 1, "triad", 24, window_s=1.0))
    assert error is None and fit is not None


def test_each_pair_gets_its_own_fit_beside_the_node_fit() -> None:
    m = _modeller()
    for i, (kernel, threads) in enumerate(SCHEDULE):
        model, fit, error = m.evaluate(_record(m, i, kernel, threads))
        assert error is None and fit is not None
        assert set(model["group_observations"]) == set(RATES)
    body = m.body()
    assert body["fit"]["n_runs"] == len(SCHEDULE) and body["total"]["runs"] == len(SCHEDULE)
    assert {name: g["runs"] for name, g in body["groups"].items()} == dict.fromkeys(RATES, len(SCHEDULE))
    # each pair's fit follows its part: on the same row, DDR_CD's fit predicts 12 % more than DDR_AB's
    from hdeem_watch.calibrate.observation import Observation

    assert m.group_fits is not None and m.group_fits.calibrators is not None
    row = Observation.from_dict(model["group_observations"]["DDR_AB"])
    predicted = {g: m.group_fits.calibrators.predicted_j(g, row) for g in ("DDR_AB", "DDR_CD")}
    assert predicted["DDR_CD"] / predicted["DDR_AB"] == pytest.approx(1.12, rel=0.01)
    assert body["min_samples"] == 100 and body["skipped"] == [] and body["alarms"] == []
    assert m.take_alarms() == []


def test_state_round_trip_and_resetting_one_group() -> None:
    m = _modeller()
    for i, (kernel, threads) in enumerate(SCHEDULE[:8]):
        m.evaluate(_record(m, i, kernel, threads))
    state = json.loads(json.dumps(m.state()))
    again = _modeller(state=state)
    assert again.restore_error is None
    assert again.body()["groups"]["DDR_EF"]["runs"] == 8 and again.body()["runs"] == 8
    again.reset("DDR_EF")
    body = again.body()
    assert body["groups"]["DDR_EF"]["runs"] == 0 and body["groups"]["DDR_AB"]["runs"] == 8
    assert body["runs"] == 8 and body["fit"] is not None  # only a full reset clears the node calibrator
    with pytest.raises(InputError, match="unknown group 'DDR_XY'"):
        again.reset("DDR_XY")
    again.reset()
    body = again.body()
    assert body["runs"] == 0 and body["total"]["runs"] == 0 and body["groups"]["DDR_AB"]["runs"] == 0
    # a state of other groups is not forced onto this node: the groups start afresh, the node fit stays
    other = RunModeller(MEMSPEC, max_requests=100_000, groups=[SensorGroup("DDR_AB", (4, 4))], dram_rates_hz=RATES,
                        state=state)
    assert other.restore_error is not None and "differ" in other.restore_error
    assert other.body()["runs"] == 8 and other.body()["groups"]["DDR_AB"]["runs"] == 0


def test_the_group_state_is_bounded_and_the_detectors_wait_for_four_runs_per_unknown() -> None:
    from hdeem_watch.calibrate.group_fits import DETECT_AFTER_RUNS, MAX_GROUP_RUNS

    m = _modeller()
    assert m.group_fits is not None and m.group_fits.calibrators is not None
    assert all(c.max_runs == MAX_GROUP_RUNS for c in m.group_fits.calibrators.calibrators.values())
    assert m.group_fits.calibrators.detect_after == DETECT_AFTER_RUNS == 24
