"""The simulated DDR5 node's DIMMs (issue 30): their memspec, its provenance, and the idle node on it.

Runs on the DDR5 node are not simulated yet (the node statistics of ``dram/node.py`` are DDR4's);
these tests hold what is there: the memspec, the model on it, the idle samples and their energy.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hdeem_watch.dram.energy_ddr5 import CURRENT_NAMES_DDR5, core_energy_ddr5
from hdeem_watch.dram.memspec_ddr5 import MemSpecDDR5
from hdeem_watch.sim.layout import DDR5_MEMSPEC, DDR5_NODE
from hdeem_watch.sim.model import model_for
from hdeem_watch.sources.sim import SimSource

ROOT = Path(__file__).resolve().parents[2]
DRAMPOWER = ROOT / "examples" / "ddr5_drampower_test.json"
NODE = ROOT / "src" / "hdeem_watch" / "sim" / DDR5_MEMSPEC
S = 1_000_000_000
#: What the node's memspec changes in DRAMPower's test memspec, and why: a 32-bit BL16 sub-channel
#: of 4 × x8 devices in 8 bank groups × 4 banks (JESD79-5's x8 organisation; one burst = one 64-byte
#: line), and the DDR5-4800B timings of tests/dram/test_ddr5_stats.py (JESD79-5 via the sources named
#: there, in cycles of tCK = 1 / 2.4 GHz).
ARCHITECTURE = {"burstLength": 16, "maxBurstLength": 16, "width": 8, "nbrOfDevices": 4, "nbrOfBankGroups": 8,
                "nbrOfBanks": 32}
TIMINGS = {"tCK": 1 / 2.4e9, "RL": 40, "WL": 38, "RCD": 40, "RP": 40, "RAS": 77, "RTP": 18, "WR": 72,
           "CCD_S_slr": 8, "CCD_L_slr": 12, "CCD_L_WR_slr": 48, "WTR_S": 6, "WTR_L": 24, "RRD_S_slr": 8,
           "RRD_L_slr": 12, "FAW_slr": 32, "REFI1": 9360, "REFI2": 4680, "RFC1_slr": 708, "RFC2_slr": 384,
           "RFCsb_slr": 312, "RTRS": 2}


def test_the_node_memspec_is_drampowers_with_only_the_named_changes() -> None:
    """No invented number: every current and voltage is DRAMPower's test memspec's; the organisation and
    timings differ only where :data:`ARCHITECTURE` and :data:`TIMINGS` say."""
    theirs = json.loads(DRAMPOWER.read_text())["memspec"]
    ours = json.loads(NODE.read_text())["memspec"]
    assert ours["mempowerspec"] == theirs["mempowerspec"]
    for section, changes in (("memarchitecturespec", ARCHITECTURE), ("memtimingspec", TIMINGS)):
        changed = {k for k in ours[section] if ours[section][k] != theirs[section].get(k)}
        assert changed <= set(changes), f"{section}: unexplained changes {sorted(changed - set(changes))}"
        assert all(ours[section][k] == v for k, v in changes.items())


def test_the_sim_models_the_ddr5_node_with_the_ddr5_energy() -> None:
    """The DDR5 node's model prices its idle DIMM with DRAMPower's DDR5 core (not DDR4's columns)."""
    model = model_for(DDR5_NODE)
    assert isinstance(model.spec, MemSpecDDR5)
    assert model.names == tuple(CURRENT_NAMES_DDR5)
    stats = model.idle_stats(1.0)
    assert stats.ranks[0].ref == pytest.approx(2.4e9 / 9360)
    columns, constant = model.linear(stats)
    assert float(columns @ model.datasheet + constant) == pytest.approx(core_energy_ddr5(model.spec, stats).core_j,
                                                                      rel=1e-12)


def test_the_idle_ddr5_node_publishes_rapl_like_sockets_whose_energy_is_the_integral(fake_clock) -> None:
    """Channels BLADE, CPU0/1, DRAM0/1 (16 sub-channels each); each DRAM channel's energy is the integral of its
    samples and near the truth's idle power of its DIMMs (sensor gain ±3 %, offset ≤ 0.3 W)."""
    clock = fake_clock()
    sim = SimSource(seed=3, clock=clock, wall_clock=lambda: 0, layout=DDR5_NODE, background_plans=False)
    assert [c.name for c in sim.channels()] == ["BLADE", "CPU0", "CPU1", "DRAM0", "DRAM1"]
    sim.open()
    clock.t = 20 * S
    batch = sim.poll()
    truth = sim.truth()
    assert truth["datasheet"]["idd5c"] == pytest.approx(0.11)  # DRAMPower's test value, a DDR5 current
    currents = sim.truth_model.currents(10.0)
    idle_w = sim.truth_node.idle_power_w(currents, sim.truth_model.temperature_c(10.0))
    for socket in (0, 1):
        name = f"DRAM{socket}"
        assert len(DDR5_NODE.sensor_dimms(name)) == 16  # 8 DIMMs × 2 sub-channels
        _, power = batch.samples[name]
        assert batch.energy_j[name] == pytest.approx(power.sum() * 0.01)
        expected = float(idle_w[DDR5_NODE.sensor_dimms(name)].sum())
        assert abs(float(np.mean(power)) - expected) <= 0.03 * expected + 0.3 + 0.125


def test_a_run_on_the_ddr5_node_is_the_integral_of_its_samples_and_its_counters_its_commands() -> None:
    """56 threads of triad on socket 0: DRAM0 rises above idle by the run plan's energy (no noise, gain or
    offset), DRAM1 stays idle, each channel's energy is the integral of its samples, and the sim's IMC
    counters over the run count exactly the reads and writes of the hidden commands (one 64-byte burst
    per line of the kernel on its sub-channels)."""
    from hdeem_watch.dram.kernels import kernel_traffic
    from hdeem_watch.sim.counters import SimCounters
    from hdeem_watch.sources.base import RunEvent

    t = [0]
    sim = SimSource(seed=5, clock=lambda: t[0], wall_clock=lambda: 0, noise=False, quantum_w=0.0, offsets=False,
                    gains=False, aging_per_h=0.0, temp_amp_c=0.0, layout=DDR5_NODE, background_plans=False)
    sim.open()
    counters = SimCounters(sim)
    t[0] = S // 10
    idle = sim.poll()
    idle_w = {ch: float(idle.samples[ch][1].mean()) for ch in ("DRAM0", "DRAM1")}
    before = counters.read()
    elements, repeat = 2_000_000, 5
    sim.on_run(RunEvent("start", "r", "triad", 56, elements, repeat, t[0]))
    plan = sim.run_plan("r")
    t[0] = S // 10 + plan.duration_ns + S // 2
    busy = sim.poll()
    after = counters.read()
    for ch in ("DRAM0", "DRAM1"):
        assert busy.energy_j[ch] - idle.energy_j[ch] == pytest.approx(busy.samples[ch][1].sum() * 0.01)  # cumulative
    above = {ch: float(busy.samples[ch][1].sum()) * 0.01 - idle_w[ch] * len(busy.samples[ch][1]) * 0.01
             for ch in ("DRAM0", "DRAM1")}
    assert plan.threads == (56, 0)
    assert above["DRAM0"] > 1e-3 and abs(above["DRAM1"]) < 1e-9, above
    traffic = kernel_traffic("triad", elements)
    names = [c.name for c in counters.channels()]
    reads = sum(after.counts[n]["cas_rd"] - before.counts[n]["cas_rd"] for n in names)
    writes = sum(after.counts[n]["cas_wr"] - before.counts[n]["cas_wr"] for n in names)
    assert reads == pytest.approx(traffic.lines_read * repeat, rel=0.02)
    assert writes == pytest.approx(traffic.lines_written * repeat, rel=0.02)


def test_the_ddr5_nodes_counters_are_sapphire_rapids_with_a_pseudo_channel_per_sub_channel() -> None:
    """Two sub-channel units make one IMC channel (8 per socket, SPR's table); each pseudo-channel's
    CASes are exactly its own sub-channel's hidden reads and writes."""
    from hdeem_watch.sim.counters import SimCounters
    from hdeem_watch.sources.base import RunEvent

    t = [0]
    sim = SimSource(seed=2, clock=lambda: t[0], wall_clock=lambda: 0, layout=DDR5_NODE, background_plans=False)
    sim.open()
    counters = SimCounters(sim)
    assert counters.table.generation == "sapphire-rapids"
    assert [c.name for c in counters.channels()] == [f"S{s}.imc{i}" for s in (0, 1) for i in range(8)]
    sim.on_run(RunEvent("start", "r", "copy", 30, 2_000_000, 3, t[0]))
    t[0] = sim.run_plan("r").duration_ns + S // 2
    snap = counters.read()
    _, hidden = sim.hidden_commands()
    cas = [sum(h.total(f) for f in ("rd", "rda", "wr", "wra")) for h in hidden]
    for n, channel in enumerate(counters.channels()):
        got = snap.counts[channel.name]
        assert got["cas_pch0"] == pytest.approx(cas[2 * n], abs=1.0)
        assert got["cas_pch1"] == pytest.approx(cas[2 * n + 1], abs=1.0)
    assert sum(snap.counts["S0.imc0"][k] for k in ("cas_pch0", "cas_pch1")) > 1000
