"""``hdeem-watch demo --node ddr5`` without processes (issue #30): the node's name, the daemon's settings
for it, the run model on the DDR5 sub-channel memspec, and the counter path of its Sapphire Rapids
IMC counters (both pseudo-channels) against an AMD UMC window (an even split over the sub-channels).

Judged against the sim's truth: the counted rows priced with the sim's hidden currents reproduce the
measured energy of the runs the counters see completely."""

from __future__ import annotations

import numpy as np
import pytest

from hdeem_watch.calibrate.counter_model import counter_groups
from hdeem_watch.calibrate.run_model import RunModeller, load_spec
from hdeem_watch.cli import main
from hdeem_watch.demo.nodes import DEMO_NODES, demo_node
from hdeem_watch.demo.sim_runs import SimRuns
from hdeem_watch.dram.linear import linear_energy
from hdeem_watch.dram.memspec_ddr5 import MemSpecDDR5
from hdeem_watch.dram.stats import stretch_stats
from hdeem_watch.errors import InputError
from hdeem_watch.sim.layout import DDR5_NODE, TAURUS
from hdeem_watch.sim.model import memspec_setting
from hdeem_watch.sources.registry import make_source, simulated_memspec


def test_an_unknown_node_is_one_line_and_exit_2(capsys) -> None:
    assert main(["demo", "--node", "ddr4", "--headless", "--duration", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["hdeem-watch: error: --node ddr4: unknown node; expected one of haswell, ddr5"]
    with pytest.raises(InputError):
        demo_node("DDR5 ")


def test_the_daemon_settings_simulate_the_ddr5_node_and_model_it_on_its_own_memspec() -> None:
    from hdeem_watch.config import load_settings

    settings = load_settings(env={}, overrides={"source": "sim", "sim_node": "ddr5"})
    source = make_source("sim", **settings.source_options())
    assert source.layout is DDR5_NODE  # type: ignore[attr-defined]
    assert simulated_memspec(source) == memspec_setting(DDR5_NODE) and memspec_setting(DDR5_NODE).endswith(".json")
    assert simulated_memspec(make_source("sim")) == TAURUS.memspec  # the Haswell node's DDR4 preset, as before
    with pytest.raises(InputError, match=r"sim node .skylake.: unknown"):
        load_settings(env={}, overrides={"source": "sim", "sim_node": "skylake"})


def test_the_run_model_prices_ddr5_and_runs_the_controller_on_a_sub_channel() -> None:
    spec = load_spec(memspec_setting(DDR5_NODE))
    assert isinstance(spec, MemSpecDDR5)
    modeller = RunModeller(memspec_setting(DDR5_NODE), topology=DDR5_NODE.topology)
    assert modeller.error is None and modeller.channel_spec.nbr_of_channels == 2
    groups = modeller.groups_for("read", 1 << 20, 112, 1)
    lines = sum(stats.total("rd") * n for stats, n in groups)
    assert lines == pytest.approx((1 << 20) * 8 / 64, rel=1e-6)  # one BL16 burst per 64-byte line


@pytest.fixture(scope="module")
def ddr5_runs() -> tuple[SimRuns, list]:
    opts = {"noise": False, "quantum_w": 0.0, "offsets": False, "gains": False, "part_spread": 0.0,
            "dimm_spread": 0.0, "io_j_per_line": 0.0, "temp_amp_c": 0.0}
    runs = SimRuns(2, counters=True, groups=False, node=DEMO_NODES["ddr5"], sim_options=opts)
    return runs, [runs.step() for _ in range(9)]  # idle and seven kernels at 112 threads, idle again


def test_the_ddr5_nodes_counters_take_the_pseudo_channel_path(ddr5_runs) -> None:
    """Sapphire Rapids' counters (the sim's): each channel becomes its two sub-channels by the
    pseudo-channels' CASes; the same window without them (an AMD UMC channel) splits evenly."""
    runs, done = ddr5_runs
    spec = runs.modeller.spec
    record = done[1].record["counters"]
    assert record["generation"] == "sapphire-rapids" and len(record["channels"]) == 16
    groups, notes = counter_groups(spec, record)
    assert len(groups) == 32 and {n for _s, n in groups} == {1}
    assert any("pseudo-channels" in n for n in notes)
    umc = {**record, "generation": "zen4",
           "channels": {c: {r: v for r, v in counts.items() if not r.startswith("cas_pch")}
                        for c, counts in record["channels"].items()}}
    even, _ = counter_groups(spec, umc)
    assert len(even) == 16 and {n for _s, n in even} == {2}
    reads = [sum(s.total("rd") + s.total("rda") for s, n in g for _ in range(n)) for g in (groups, even)]
    assert reads[0] == pytest.approx(reads[1], rel=1e-9)


def test_counted_ddr5_rows_at_the_sims_currents_give_the_measured_energy(ddr5_runs) -> None:
    """Saturated runs (no active power-down, which Sapphire Rapids cannot count) and idle runs: the
    counted statistics priced with the sim's hidden currents are the measured energy within 1.5 %."""
    runs, done = ddr5_runs
    spec = runs.modeller.spec
    truth = runs.sim.truth_model.currents(runs.t_s).mean(axis=0)
    for run in done:
        groups, _ = counter_groups(spec, run.record["counters"])
        energy = 0.0
        for stats, n in groups:
            lin = linear_energy(spec, stretch_stats(spec, stats, run.record["window_s"]))
            energy += n * (float(np.asarray(lin.columns) @ truth) + lin.constant_j)
        assert energy == pytest.approx(run.record["dram_energy_j"], rel=0.015), run.record["name"]


def test_a_ddr5_runs_calibrated_prediction_prices_each_current_in_its_own_column() -> None:
    """The calibrated vector is built in DDR5's current order (DDR5 has IDD5C, DDR4 IDD5F2/F4 in
    other places): a fit that changes only IDD2P moves only the IDD2P column's share of a
    prediction. (It was built in DDR4's order: IDD2P's column got IDD3P's value.)"""
    from hdeem_watch.calibrate.observation import current_names

    modeller = RunModeller(memspec_setting(DDR5_NODE), topology=DDR5_NODE.topology)
    names = current_names(modeller.spec)
    datasheet, _ = modeller._currents_vector(None)
    assert list(datasheet) == [float(modeller.spec.currents.get(n, 0.0)) for n in names]
    fitted, intercept = modeller._currents_vector({"currents": {"idd2p": {"calibrated": 0.001}}, "intercept_j": 0.5})
    changed = [n for n, a, b in zip(names, datasheet, fitted, strict=True) if a != b]
    assert changed == ["idd2p"] and fitted[names.index("idd2p")] == 0.001 and intercept == 0.5
