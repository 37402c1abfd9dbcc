"""The simulated node with RAPL-like DRAM sensors, one per socket (the Sapphire Rapids layout, issue 30)."""

from __future__ import annotations

from hdeem_watch.sources.base import RunEvent
from hdeem_watch.sources.sim import SimSource
from hdeem_watch.sources.sim_layout import SAPPHIRE_RAPIDS, SimLayout

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
