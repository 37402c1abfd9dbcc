"""Counted fits per socket (calibrate/socket_fits.py, run_model.RunModeller): issue #30.

Two sockets whose parts differ (socket 1's currents 12 % above socket 0's) measured by one RAPL
DRAM sensor each, with counted windows as Sapphire Rapids' IMC gives them (both pseudo-channels, no
per-rank CKE counter). Half the runs load socket 0 only (threads fill socket 0 first), and their
mixes of activations and bursts differ from the runs that load both: one fit of the node's total
then puts socket 1's higher currents into the wrong columns. The truth is each socket's currents
priced on the counted commands (plus an I/O energy per burst and a sensor offset), its DIMM mean
the node's truth; never a fit.
"""

from __future__ import annotations

import dataclasses
import pathlib

import numpy as np
import pytest

from hdeem_watch.calibrate.counter_model import counter_groups
from hdeem_watch.calibrate.group_rows import SensorGroup
from hdeem_watch.calibrate.run_model import RunModeller
from hdeem_watch.calibrate.socket_fits import combine, socket_sensors
from hdeem_watch.dram.energy_ddr5 import core_energy_ddr5
from hdeem_watch.dram.memspec_ddr5 import load_memspec_ddr5
from hdeem_watch.run_record import RunRecord

MEMSPEC = pathlib.Path(__file__).parents[2] / "src" / "hdeem_watch" / "sim" / "ddr5_node.json"
SOCKETS = (SensorGroup("DRAM0", (8, 0)), SensorGroup("DRAM1", (0, 8)))
CURRENTS = ("idd0", "idd2n", "idd3n", "idd4r", "idd4w", "idd2p", "idd3p")
#: socket → its part's currents relative to the datasheet (socket 1 a 12 % hungrier part)
PART = {"DRAM0": 0.55, "DRAM1": 0.55 * 1.12}
IO_J_PER_BURST = 0.3e-9


def test_socket_sensors_are_rapl_domains_not_hdeem_pairs() -> None:
    assert socket_sensors(SOCKETS) == {"DRAM0": 8, "DRAM1": 8}
    pairs = [SensorGroup("DDR_AB", (2, 0)), SensorGroup("DDR_CD", (2, 0)), SensorGroup("DDR_EF", (0, 2))]
    assert socket_sensors(pairs) == {}  # two sensors share socket 0
    assert socket_sensors([SensorGroup("DRAM", (8, 8))]) == {}  # one sensor over both sockets
    assert socket_sensors([SensorGroup("DRAM0", (8, 0))]) == {}  # one socket: the node fit is its fit


def _window(rng: np.random.Generator, window_s: float, load: dict[str, tuple[float, float, float]]) -> dict:
    """Sapphire Rapids-like counters of 8 channels per socket: ``load[sensor] = (reads, writes,
    activations)`` per channel and second (socket without load: refresh only)."""
    dclk = window_s / 0.4167e-9
    channels, sensors = {}, {}
    for socket, sensor in enumerate(("DRAM0", "DRAM1")):
        reads, writes, acts = load.get(sensor, (0.0, 0.0, 0.0))
        for imc in range(8):
            jitter = float(rng.uniform(0.97, 1.03))
            rd, wr, act = reads * window_s * jitter, writes * window_s * jitter, acts * window_s * jitter
            name = f"S{socket}.imc{imc}"
            sensors[name] = sensor
            channels[name] = {"dclk": dclk, "cas_rd": rd, "cas_wr": wr, "cas_rd_autopre": 0.0, "cas_wr_autopre": 0.0,
                              "act": act, "pre_page_miss": 0.75 * act, "pre_page_close": 0.25 * act,
                              "pre_underfill": 0.0, "refresh": 0.0, "ppd_cycles": 0.0 if act else 0.9 * dclk,
                              "sref_cycles": 0.0, "cas_pch0": (rd + wr) / 2, "cas_pch1": (rd + wr) / 2}
    return {"source": "sim", "status": "ok", "ranks": 1, "refresh_complete": False, "window_s": window_s,
            "sensors": sensors, "channels": channels}


def _true_energy(spec, counters: dict, sensor: str, rng: np.random.Generator) -> float:
    """The sensor's energy: its channels' counted commands priced with its part's currents, I/O per burst, offset."""
    part = spec.with_currents({n: v * (PART[sensor] if n in CURRENTS else 1.0) for n, v in spec.currents.items()})
    mine = {**counters, "channels": {c: v for c, v in counters["channels"].items() if counters["sensors"][c] == sensor}}
    groups, _ = counter_groups(spec, mine)
    core = sum(n * core_energy_ddr5(part, stats).core_j for stats, n in groups)
    bursts = sum(v["cas_rd"] + v["cas_wr"] for v in mine["channels"].values())
    return (core + IO_J_PER_BURST * bursts + 0.2 * counters["window_s"]) * (1 + rng.normal(0, 0.002))


def _runs(count: int) -> list[RunRecord]:
    rng = np.random.default_rng(7)
    spec = load_memspec_ddr5(MEMSPEC)
    # (reads, writes, activations) per channel and second: streaming mixes on both sockets, other
    # mixes (fewer activations per burst) on socket 0 alone
    both = [(2.0e8, 0.0, 2.5e7), (1.3e8, 0.7e8, 3.0e7), (1.0e8, 1.0e8, 5.0e7), (0.0, 1.6e8, 2.0e7)]
    alone = [(1.2e8, 0.0, 3.0e6), (0.6e8, 0.3e8, 2.0e6), (0.4e8, 0.4e8, 1.5e7), (0.0, 0.8e8, 1.0e6)]
    records = []
    for i in range(count):
        window_s = 1.5 + (i % 5) * 0.4
        kind = i % 9
        if kind == 8:
            load, name = {}, "idle"
        elif kind < 4:
            load, name = {"DRAM0": both[kind], "DRAM1": both[kind]}, f"both{kind}"
        else:
            load, name = {"DRAM0": alone[kind - 4]}, f"alone{kind - 4}"
        counters = _window(rng, window_s, load)
        energy = {s: _true_energy(spec, counters, s, rng) for s in ("DRAM0", "DRAM1")}
        records.append(RunRecord.from_dict({
            "run_id": f"r{i + 1}", "state": "modelling", "name": name, "kernel": "opaque" if name != "idle" else "idle",
            "threads": 0, "elements": 0, "repeat": 1, "window_s": window_s, "t_stop_ns": (i + 1) * 10**10,
            "energy_j": energy, "dram_energy_j": sum(energy.values()), "counters": counters}))
    return records


@pytest.fixture(scope="module")
def fitted() -> tuple[RunModeller, RunModeller, list[RunRecord]]:
    records = _runs(45)
    both = [RunModeller(str(MEMSPEC), dimms=16, currents=CURRENTS, groups=SOCKETS, trust=False) for _ in range(2)]
    both[1].socket_fits = None  # the node fit of the summed rows alone (the code before per-socket fits)
    for modeller in both:
        for record in records[:36]:
            _model, _fit, error = modeller.evaluate(record)
            assert error is None, error
    return both[0], both[1], records[36:]


def test_the_node_figure_is_the_sockets_dimm_mean(fitted) -> None:
    per_socket, node_only, _late = fitted
    shown = per_socket.latest_fit()
    sockets = shown["trust"]["per_socket"]
    assert set(sockets) == {"DRAM0", "DRAM1"}
    for name in CURRENTS:
        mean = (sockets["DRAM0"][name]["calibrated"] + sockets["DRAM1"][name]["calibrated"]) / 2
        assert shown["currents"][name]["calibrated"] == pytest.approx(mean, rel=1e-12)
    # the hungrier part's socket fits higher currents; the node fit of the sums has no per-socket view
    assert sockets["DRAM1"]["idd4w"]["calibrated"] > 1.05 * sockets["DRAM0"]["idd4w"]["calibrated"]
    assert "per_socket" not in (node_only.latest_fit()["trust"] or {})
    # what was fitted is shown: the summed fit's runs and residuals stay the node's
    assert shown["n_runs"] == 36 and shown["error"] == per_socket.calibrator.latest.to_dict()["error"]


def test_a_run_is_predicted_per_socket_with_each_sockets_fit(fitted) -> None:
    per_socket, node_only, late = fitted
    worst = {}
    for label, modeller in (("per_socket", per_socket), ("node", node_only)):
        errors = []
        for record in late:  # runs the fits never saw: each is predicted before it is fitted
            model, _fit, _error = modeller.evaluate(record)
            errors.append(abs(model["calibrated_j"] / record.dram_energy_j - 1))
        worst[label] = max(errors)
    assert worst["per_socket"] <= 0.005 and worst["per_socket"] < worst["node"] / 2, worst


def test_state_keeps_the_socket_fits(fitted) -> None:
    per_socket, _node, _late = fitted
    state = per_socket.state()
    assert set(state["socket_fits"]["calibrators"]) == {"DRAM0", "DRAM1"}
    again = RunModeller(str(MEMSPEC), dimms=16, currents=CURRENTS, groups=SOCKETS, trust=False, state=state)
    assert again.restore_error is None and again.socket_fits is not None
    shown = again.refit()
    assert shown is not None and "per_socket" in shown["trust"]
    for name in ("idd0", "idd4w"):
        assert shown["currents"][name]["calibrated"] == pytest.approx(
            per_socket.latest_fit()["currents"][name]["calibrated"], rel=1e-6)


def test_a_run_without_counters_leaves_the_socket_fits_alone(fitted) -> None:
    per_socket, _node, late = fitted
    before = {s: len(c.observations) for s, c in per_socket.socket_fits.calibrators.items()}
    record = RunRecord.from_dict({**late[0].to_dict(), "run_id": "r999", "counters": None, "kernel": "idle",
                                  "name": "idle"})
    _model, _fit, error = per_socket.evaluate(record)
    assert error is None
    assert {s: len(c.observations) for s, c in per_socket.socket_fits.calibrators.items()} == before


def test_combine_holds_what_a_socket_holds_and_adds_widths_in_quadrature(fitted) -> None:
    per_socket, _node, _late = fitted
    fits = {s: c.latest for s, c in per_socket.socket_fits.calibrators.items()}
    base = per_socket.calibrator.latest
    j = base.currents.index("idd4w")
    held = {s: dataclasses.replace(f, trust={"held": {"idd4w": {}}}, identifiable=np.zeros(len(f.currents), bool))
            for s, f in fits.items()}
    shown_held = combine(held, {"DRAM0": 8, "DRAM1": 8}, base)
    assert not shown_held.identifiable[j]
    # undetermined: the plain sum of the weighted half-widths (bounds, not noise)
    halves_held = [f.ci95_a[j, 1] - f.calibrated_a[j] for f in held.values()]
    assert shown_held.ci95_a[j, 1] - shown_held.calibrated_a[j] == pytest.approx(sum(halves_held) / 2, rel=1e-9)
    sure = {s: dataclasses.replace(f, identifiable=np.ones(len(f.currents), bool)) for s, f in fits.items()}
    for chosen in (fits, sure):
        shown = combine(chosen, {"DRAM0": 8, "DRAM1": 8}, base)
        for k, name in enumerate(shown.currents):  # determined: in quadrature; not: summed
            halves = [f.ci95_a[k, 1] - f.calibrated_a[k] for f in chosen.values()]
            expected = np.hypot(*halves) / 2 if shown.identifiable[k] else sum(halves) / 2
            assert shown.ci95_a[k, 1] - shown.calibrated_a[k] == pytest.approx(expected, rel=1e-9), name
    assert shown.identifiable.all()  # every socket determines every current: so does the node


def test_with_socket_fits_the_summed_node_fit_keeps_only_its_holds() -> None:
    """Its intervals are not shown: no jackknife, no draws (the sockets' fits keep theirs)."""
    modeller = RunModeller(str(MEMSPEC), dimms=16, currents=CURRENTS, groups=SOCKETS)
    assert modeller.calibrator.trust.jackknife is False and modeller.calibrator.trust.draws == 0
    assert modeller.calibrator.trust.anchors  # it still holds IDD2N
    assert all(c.trust.jackknife for c in modeller.socket_fits.calibrators.values())
    pairs = RunModeller(str(MEMSPEC), dimms=16, currents=CURRENTS,
                        groups=(SensorGroup("DDR_AB", (8, 0)), SensorGroup("DDR_CD", (8, 0))))
    assert pairs.socket_fits is None and pairs.calibrator.trust.jackknife is True
