"""The simulated node with RAPL-like DRAM sensors, one per socket (the Sapphire Rapids layout, issue 30)."""

from __future__ import annotations

import pathlib

import numpy as np
import pytest

from hdeem_watch.dram.energy_ddr5 import CURRENT_NAMES_DDR5, core_energy_ddr5
from hdeem_watch.dram.memspec_ddr5 import load_memspec_ddr5
from hdeem_watch.dram.stats import CommandStats
from hdeem_watch.sim.layout import SAPPHIRE_RAPIDS, SimLayout
from hdeem_watch.sim.power import PowerPhysics, busy_rank, idle_columns, refresh_per_s, split_columns
from hdeem_watch.sources.base import RunEvent
from hdeem_watch.sources.sim import SimSource

S = 1_000_000_000


def test_per_socket_layout_has_one_dram_sensor_per_socket_over_all_its_channels() -> None:
    """``DRAM0`` covers DIMMs A–H (socket 0), ``DRAM1`` DIMMs I–P (socket 1); nothing is split."""
    assert SAPPHIRE_RAPIDS.channels == ("BLADE", "CPU0", "CPU1", "DRAM0", "DRAM1")
    assert [SAPPHIRE_RAPIDS.dimm_names[d] for d in SAPPHIRE_RAPIDS.sensor_dimms("DRAM0")] == list("ABCDEFGH")
    assert [SAPPHIRE_RAPIDS.dimm_names[d] for d in SAPPHIRE_RAPIDS.sensor_dimms("DRAM1")] == list("IJKLMNOP")
    assert SimLayout.per_socket(1, 4, 3).sensors == ("DRAM0",)


def test_a_run_on_socket_0_lands_on_dram0_only() -> None:
    """56 threads fill socket 0 of the SPR-like node: DRAM0 rises above idle, DRAM1 stays idle."""
    t = [0]
    sim = SimSource(seed=5, clock=lambda: t[0], wall_clock=lambda: 1_700_000_000 * S, noise=False, quantum_w=0.0,
                    io_j_per_line=0.0, offsets=False, gains=False, aging_per_h=0.0, temp_amp_c=0.0,
                    layout=SAPPHIRE_RAPIDS, background_plans=False)
    sim.open()
    t[0] = S // 10
    idle = sim.poll()
    idle_w = {ch: float(idle.samples[ch][1].mean()) for ch in ("DRAM0", "DRAM1")}
    sim.on_run(RunEvent("start", "r", "triad", 56, 2_000_000, 5, t[0]))
    plan = sim.run_plan("r")
    t[0] = S // 10 + plan.duration_ns + S // 2
    busy = sim.poll()
    above = {ch: float(busy.samples[ch][1].sum()) * 0.01 - idle_w[ch] * len(busy.samples[ch][1]) * 0.01
             for ch in ("DRAM0", "DRAM1")}
    assert plan.threads == (56, 0)
    assert above["DRAM0"] > 1e-3, above
    assert abs(above["DRAM1"]) < 1e-9, above


def test_sim_power_prices_a_ddr5_rank_with_the_ddr5_model() -> None:
    """The sim's rank physics on DRAMPower's DDR5 test memspec: columns over the DDR5 currents whose
    sum at the memspec's currents is the DDR5 core energy; no refresh (the toy gives REFI1 = 0)."""
    spec = load_memspec_ddr5(pathlib.Path(__file__).parents[2] / "examples" / "ddr5_drampower_test.json")
    assert refresh_per_s(spec, 40.0) == 0.0
    stats = CommandStats(ranks=(busy_rank(spec, 1.0, 40.0, 1e7, 5e6, 2e6, 1.5e7, PowerPhysics()),))
    background, command, constant = split_columns(spec, stats)
    currents = np.array([spec.currents[n] for n in CURRENT_NAMES_DDR5])
    assert (background + command) @ currents + constant == pytest.approx(core_energy_ddr5(spec, stats).core_j,
                                                                         rel=1e-12)
    assert command @ currents > 0 and idle_columns(spec, False)[0].shape == (len(CURRENT_NAMES_DDR5),)
