"""Per-sensor-group calibration (calibrate/groups.py) on a synthetic node that is not the model
(tests/calibrate/calib_node.py): rows per group from the sensor map, guard rails, drift alarms,
sibling comparison, the calib.get body and persistence."""

from __future__ import annotations

import json
from types import ModuleType
from typing import Any

import numpy as np
import pytest

from hdeem_watch.calibrate.groups import NODE, GroupCalibrators, SensorGroup, group_observation, sensor_groups
from hdeem_watch.errors import InputError
from hdeem_watch.run_record import RunRecord

from .conftest import _load

# One worker runs the module, so its module-scoped fixture is built once, not once per worker.
pytestmark = pytest.mark.xdist_group("calibrate-groups")

NODE_SIM: ModuleType = _load("calib_node")


@pytest.fixture(scope="module")
def spec() -> Any:
    from hdeem_watch.dram.memspec import preset

    return preset("samsung-m393a1g43db0-cpb")


@pytest.fixture(scope="module")
def planned(spec: Any) -> list[Any]:
    return NODE_SIM.plan(spec)


def test_sensor_map_gives_groups_per_socket() -> None:
    """The node's sensor map (sensor → DIMM locators) and each DIMM's socket give the groups; a DIMM
    on an unknown socket is a one-line error naming the sensor and the DIMM."""
    from hdeem_watch.node.description import Dimm, NodeDescription
    from hdeem_watch.node.facts import Fact
    from hdeem_watch.node.sensors import sensor_map

    one = Fact(1, "t")
    dimms = tuple(Dimm(f"{'ABCDEFGH'[s * 4 + c]}1", socket=s, channel=c) for s in range(2) for c in range(4))
    node = NodeDescription(Fact(2, "t"), Fact(12, "t"), Fact(4, "t"), one, one, Fact(4, "t"), one, dimms=dimms)
    sockets = {d.locator: d.socket for d in dimms}
    groups = sensor_groups(sensor_map(node), sockets, 2, prefix="DDR_")
    assert groups == [SensorGroup("DDR_AB", (2, 0)), SensorGroup("DDR_CD", (2, 0)),
                      SensorGroup("DDR_EF", (0, 2)), SensorGroup("DDR_GH", (0, 2))]
    rapl = sensor_groups(sensor_map(node), sockets, 2, prefix="DRAM")
    assert rapl == [SensorGroup("DRAM0", (4, 0)), SensorGroup("DRAM1", (0, 4))]
    with pytest.raises(InputError, match="DDR_AB: DIMM 'Z9' has socket None"):
        sensor_groups({"DDR_AB": ["Z9"]}, sockets, 2)


def test_group_row_is_its_sockets_rows_and_node_row_their_sum(spec: Any, planned: list[Any]) -> None:
    """A group's row is its socket's one-channel row × its DIMMs; the node row (all groups fitted)
    is the sum of the group rows against the summed energy."""
    from hdeem_watch.calibrate.rows import node_observation

    p = planned[4]  # assign on 24 threads: both sockets busy
    calib = GroupCalibrators(spec, NODE_SIM.sensor_groups())
    energies = {"DDR_AB": 10.0, "DDR_CD": 11.0, "DDR_EF": 9.0, "DDR_GH": 9.5}
    from hdeem_watch.calibrate.groups import MeasuredRun

    update = calib.add_run(MeasuredRun("r1", 10, 2.0, p.socket_stats, energies))
    node_obs = calib.calibrators[NODE].observations[0]
    expected = node_observation(spec, list(p.socket_stats), 2.0, sum(energies.values()))
    assert np.allclose(node_obs.columns, expected.columns) and node_obs.measured_j == pytest.approx(39.5)
    ef = group_observation(spec, p.socket_stats, SensorGroup("DDR_EF", (0, 2)), 2.0, 9.0)
    assert np.allclose(calib.calibrators["DDR_EF"].observations[0].columns, ef.columns)
    assert set(update.fits) == {"DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH", NODE}


def test_short_and_unmeasured_runs_are_recorded_not_fitted(spec: Any, planned: list[Any]) -> None:
    """A 10 ms run (one sample per sensor) is skipped in every group and the node, with the reason;
    a sensor without an energy (NaN) skips that group and the node only."""
    calib = GroupCalibrators(spec, NODE_SIM.sensor_groups())
    node = NODE_SIM.SyntheticNode(spec, 0, planned=planned)
    update = calib.add_run(node.run(config=2, duration_s=0.01))
    assert not update.fits
    assert {s.group for s in update.skipped} == {"DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH", NODE}
    assert "1 samples of DDR_AB in 0.01 s; at least 100 are needed" in update.skipped[0].reason
    run = node.run(config=2)
    energies = dict(run.energy_j, DDR_CD=float("nan"))
    from dataclasses import replace

    update = calib.add_run(replace(run, energy_j=energies))
    assert set(update.fits) == {"DDR_AB", "DDR_EF", "DDR_GH"}
    assert [s.group for s in update.skipped] == ["DDR_CD", NODE]
    assert all(len(c.observations) == 0 for g, c in calib.calibrators.items() if g in ("DDR_CD", NODE))
    body = calib.body()
    assert len(body["skipped"]) == 7 and body["min_samples"] == 100


def test_each_group_gets_its_own_currents(spec: Any, planned: list[Any]) -> None:
    """Groups that differ by part variation (±10 %) get their own fits: on 20 runs the groups' IDD2N
    and IDD3N (the background currents) are on average nearer their own truth than the node fit
    (observed 1.7–2.7 % against 4.3–5 % over seeds 0–5), and the node-level LOO stays ≤ 5 %."""
    node = NODE_SIM.SyntheticNode(spec, 3, planned=planned)
    calib = GroupCalibrators(spec, NODE_SIM.sensor_groups(), calibrator={"half_life_s": None, "loo": "exact"})
    for i in range(20):
        calib.add_run(node.run(config=i % len(planned)))
    node_fit = calib.calibrators[NODE].latest
    assert node_fit is not None and node_fit.error_loo <= 0.05
    own, shared = [], []
    for name, _counts in NODE_SIM.GROUPS:
        fit = calib.calibrators[name].latest
        assert fit is not None and fit.n_runs == 20
        for current in ("idd2n", "idd3n"):
            own.append(abs(fit.calibrated[current] / node.truth[name][current] - 1))
            shared.append(abs(node_fit.calibrated[current] / node.truth[name][current] - 1))
    assert np.mean(own) < 0.75 * np.mean(shared), (np.mean(own), np.mean(shared))


@pytest.mark.slow  # a long end-to-end detection check (two sim-hours through the group fits, ~5 s of CPU)
def test_aging_pair_raises_an_alarm_naming_it_and_no_other(spec: Any, planned: list[Any]) -> None:
    """+30 %/h on DDR_CD's currents from sim minute 40 on: the residual CUSUM raises an alarm for
    DDR_CD within 10 sim-minutes, and none for the other pairs; the same node without aging raises
    none in the same time."""
    def stream(aging: dict[str, float]) -> tuple[GroupCalibrators, list[Any], Any]:
        node = NODE_SIM.SyntheticNode(spec, 11, planned=planned, aging=aging, age_start_s=2400.0)
        calib = GroupCalibrators(spec, NODE_SIM.sensor_groups(), calibrator={"half_life_s": 3600.0})
        alarms = []
        while node.clock_s < 3600.0:
            alarms += calib.add_run(node.run()).alarms
        return calib, alarms, node

    _calib, alarms, _node = stream({})
    assert alarms == []
    calib, alarms, _node = stream({"DDR_CD": 0.3})
    residual = [a for a in alarms if a.kind == "residual-cusum"]
    assert residual and {a.group for a in residual} <= {"DDR_CD", NODE}, alarms
    first = min(a.time_ns for a in residual if a.group == "DDR_CD")
    assert 2400e9 < first <= 3000e9, first / 1e9
    assert calib.body()["groups"]["DDR_CD"]["alarms"]


def test_sibling_change_is_named_and_a_different_part_is_not(spec: Any, planned: list[Any]) -> None:
    """A pair that is a different part from the start (currents 40 % above its siblings') raises
    no sibling alarm — its ratio to them holds; when its currents then jump by 60 % (after its
    reference fit), the sibling comparison names it, once per current, and no other pair."""
    node = NODE_SIM.SyntheticNode(spec, 5, planned=planned)
    node.truth["DDR_AB"] = {n: v * 1.4 for n, v in node.truth["DDR_AB"].items()}
    calib = GroupCalibrators(spec, NODE_SIM.sensor_groups(), calibrator={"half_life_s": 600.0})
    alarms = []
    for i in range(30):
        alarms += calib.add_run(node.run(config=i % len(planned))).alarms
    assert [a for a in alarms if a.kind == "sibling"] == [] and set(calib.reference) == set(calib.groups)
    node.truth["DDR_GH"] = {n: v * 1.6 for n, v in node.truth["DDR_GH"].items()}
    for i in range(40):
        alarms += calib.add_run(node.run(config=i % len(planned))).alarms
    siblings = [a for a in alarms if a.kind == "sibling"]
    assert siblings and {a.group for a in siblings} == {"DDR_GH"}, siblings
    assert len({(a.group, a.current) for a in siblings}) == len(siblings)
    assert all(a.direction == "up" and a.statistic > 0.15 for a in siblings)


def test_body_is_json_and_state_round_trips(spec: Any, planned: list[Any]) -> None:
    """``body()`` is strict JSON with groups and node; ``to_dict``/``from_dict`` restore the same
    fits; reset of one group leaves the others."""
    node = NODE_SIM.SyntheticNode(spec, 2, planned=planned)
    calib = GroupCalibrators(spec, NODE_SIM.sensor_groups())
    for i in range(8):
        calib.add_run(node.run(config=i % len(planned)))
    body = json.loads(json.dumps(calib.body(), allow_nan=False))
    assert set(body["groups"]) == {"DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH"} and body["total"]["runs"] == 8
    assert body["groups"]["DDR_EF"]["dimms_per_socket"] == [0, 2]
    state = json.loads(json.dumps(calib.to_dict(), allow_nan=False))
    again = GroupCalibrators.from_dict(state, spec)
    for name in [*calib.groups, NODE]:
        a, b = calib.calibrators[name].latest, again.calibrators[name].latest
        assert a is not None and b is not None
        assert np.allclose(a.calibrated_a, b.calibrated_a)
    again.reset("DDR_AB")
    assert again.body()["groups"]["DDR_AB"]["runs"] == 0 and again.body()["groups"]["DDR_CD"]["runs"] == 8
    with pytest.raises(InputError, match="unknown group 'DDR_XY'"):
        again.reset("DDR_XY")


def test_a_daemon_record_becomes_a_measured_run(spec: Any, planned: list[Any]) -> None:
    """A run record's per-channel energies and window (with the sensors' rates) make the groups'
    input; a 10 ms record is skipped with the reason, a 2 s one fitted."""
    from hdeem_watch.calibrate.groups import measured_run, unmeasured_reason

    rates = {"DDR_AB": 100.0, "DDR_CD": 100.0, "DDR_EF": 100.0, "DDR_GH": 100.0}
    calib = GroupCalibrators(spec, NODE_SIM.sensor_groups())
    for window, fitted in ((0.01, False), (2.0, True)):
        record = {"run_id": "r1", "name": "triad", "t_stop_ns": 5, "window_s": window,
                  "energy_j": {"BLADE": 900.0 * window, "DDR_AB": 5.0 * window, "DDR_CD": 5.1 * window,
                               "DDR_EF": 4.0 * window, "DDR_GH": None}}
        run = measured_run(RunRecord.from_dict({"state": "modelling", **record}), planned[2].socket_stats, rates)
        assert run.name == "r1:triad" and run.samples is not None and run.samples["DDR_AB"] == int(window * 100)
        update = calib.add_run(run)
        assert ("DDR_AB" in update.fits) is fitted
        assert any("no measured energy of DDR_GH (nan)" in s.reason for s in update.skipped)
    assert unmeasured_reason("r", "DDR_AB", 1.0, 100, 1.0) is None


def test_one_model_for_the_whole_node_stands_for_every_socket(spec: Any) -> None:
    """The daemon models an idle run as ONE channel's statistics for all DIMMs: each group's row is
    then that row × its DIMMs."""
    from hdeem_watch.calibrate.rows import observation_from_run
    from hdeem_watch.dram.node import idle_channel_stats

    idle = idle_channel_stats(spec)
    row = group_observation(spec, [(idle, 8)], SensorGroup("DDR_EF", (0, 2)), 3.0, 4.0)
    single = observation_from_run(spec, idle, 3.0, 4.0)
    assert np.allclose(row.columns, 2 * single.columns)


def test_calib_show_reads_the_group_shape(spec: Any, planned: list[Any]) -> None:
    """``hdeem-watch calib show`` reads the body of a daemon with groups: node first (the daemon's node
    fit, not the groups' sum), then ``total`` (the groups' sum) and each group; --group picks one, an
    unknown one is a one-line error listing the groups; alarms are printed."""
    from hdeem_watch.cli.calib import _select, fits_of, format_fits

    node = NODE_SIM.SyntheticNode(spec, 4, planned=planned)
    calib = GroupCalibrators(spec, NODE_SIM.sensor_groups(), calibrator={"half_life_s": 600.0})
    for i in range(70):
        if i == 30:  # after the reference fits: DDR_GH's currents jump
            node.truth["DDR_GH"] = {n: v * 1.6 for n, v in node.truth["DDR_GH"].items()}
        calib.add_run(node.run(config=i % len(planned)))
    body = json.loads(json.dumps(calib.body(), allow_nan=False))
    fits = fits_of(body)
    assert list(fits) == ["node", "total", "DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH"]
    assert fits["node"]["fit"] is None and fits["total"]["fit"]["n_runs"] == 70  # a body without the node fit
    text = format_fits(_select(fits, "DDR_GH"), [a for a in body["alarms"] if a["group"] == "DDR_GH"], [])
    assert text.startswith("DDR_GH: 70 runs") and "ALARM DDR_GH" in text and "sibling" in text
    with pytest.raises(InputError, match="--group DDR_XY: unknown group; this daemon has node, total, DDR_AB"):
        _select(fits, "DDR_XY")


def test_a_version_1_state_keeps_its_fits_and_starts_the_detectors_afresh(spec: Any, planned: list[Any]) -> None:
    """A state saved before the same-kind detectors (version 1: detectors on plain residuals, no
    kinds, no references) restores the fits; its detectors judged other inputs and start again."""
    node = NODE_SIM.SyntheticNode(spec, 3, planned=planned)
    calib = GroupCalibrators(spec, NODE_SIM.sensor_groups())
    for i in range(30):
        calib.add_run(node.run(config=i % len(planned)))
    state = json.loads(json.dumps(calib.to_dict(), allow_nan=False))
    assert state["version"] == 2 and state["reference"] and state["last_of_kind"]["DDR_AB"]
    old = {k: v for k, v in state.items() if k not in ("reference", "last_of_kind")}
    old["version"] = 1
    old["detectors"]["DDR_AB"] = {"k": 0.5, "h": 12.0, "warmup": 20, "learning": [], "scale": 0.05,
                                  "upper": 3.0, "lower": 0.0, "alarmed": False}
    again = GroupCalibrators.from_dict(old, spec)
    assert again.calibrators["DDR_AB"].latest is not None and again.reference == {}
    detector = again.detectors["DDR_AB"]
    assert (detector.k, detector.h, detector.upper, detector.learning) == (1.0, 10.0, 0.0, [])
    restored = GroupCalibrators.from_dict(state, spec)
    assert restored.reference == calib.reference
    assert list(restored.last_of_kind["DDR_AB"]) == list(calib.last_of_kind["DDR_AB"])
