"""The simulated node takes any node (issue 15): a 2 × 28-core Ice Lake, a 1-socket node, Taurus by default."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hdeem_watch.errors import InputError
from hdeem_watch.node.description import describe_node
from hdeem_watch.sim.layout import TAURUS, SimLayout, layout_for_node
from hdeem_watch.sim.model import kernel_traffic_lines, modelled_line_rate
from hdeem_watch.sources.base import CHANNELS, RunEvent, hdeem_channel_infos
from hdeem_watch.sources.sim import SimSource, channel_infos

S = 1_000_000_000
ICE_LAKE_1DPC = SimLayout.regular(2, 28, 8)      # 2 x Xeon Gold 6330, 16 DIMMs
ONE_SOCKET = SimLayout.regular(1, 12, 6)         # 1 x Xeon Silver 4116, 6 DIMMs


class Clock:
    def __init__(self) -> None:
        self.t = 0

    def __call__(self) -> int:
        return self.t


def quiet_sim(clock: Clock, layout: SimLayout) -> SimSource:
    sim = SimSource(seed=5, clock=clock, wall_clock=lambda: 1_700_000_000 * S, noise=False, quantum_w=0.0,
                    io_j_per_line=0.0, offsets=False, gains=False, aging_per_h=0.0, temp_amp_c=0.0, layout=layout,
                    background_plans=False)
    sim.open()
    return sim


def test_taurus_is_the_default_and_hdeems_channel_set() -> None:
    """The default layout is HDEEM's Haswell-EP blade: its channels are base.CHANNELS, in that order."""
    assert TAURUS.channels == CHANNELS
    assert channel_infos(TAURUS) == hdeem_channel_infos()
    assert SimSource(seed=1).layout is TAURUS


def test_layout_from_the_detected_taurus_node(node_trees: Path) -> None:
    """The Taurus fixture's description gives the default layout."""
    node = describe_node(node_trees / "haswell-ep-taurus" / "sys",
                         (node_trees / "haswell-ep-taurus" / "dmidecode.txt").read_text(), "fixture")
    assert layout_for_node(node) == TAURUS


def test_layout_needs_counts_and_one_dimm_per_channel(node_trees: Path, tmp_path: Path) -> None:
    """Unknown counts and 2 DIMMs per channel are clear errors, not a wrong model."""
    with pytest.raises(InputError, match="does not know sockets"):
        layout_for_node(describe_node(tmp_path, None, "none"))
    icelake = node_trees / "icelake-sp-2dpc"
    with pytest.raises(InputError, match="2 DIMMs per channel"):
        layout_for_node(describe_node(icelake / "sys", (icelake / "dmidecode.txt").read_text(), "fixture"))


@pytest.mark.parametrize(("layout", "channels"), [
    (ICE_LAKE_1DPC, ("BLADE", "CPU0", "CPU1", "DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH", "DDR_IJ", "DDR_KL",
                     "DDR_MN", "DDR_OP")),
    (ONE_SOCKET, ("BLADE", "CPU0", "DDR_AB", "DDR_CD", "DDR_EF")),
])
def test_channels_of_other_nodes(layout: SimLayout, channels: tuple[str, ...]) -> None:
    """One CPU channel per socket, one DRAM sensor per pair of channels; every channel sampled."""
    clock = Clock()
    sim = quiet_sim(clock, layout)
    assert tuple(i.name for i in sim.channels()) == channels
    clock.t = S // 10
    batch = sim.poll()
    assert set(batch.samples) == set(channels)
    assert len(batch.samples["BLADE"][0]) == 100 and len(batch.samples["CPU0"][0]) == 10
    assert len(sim.truth()["dimms"]) == len(layout.dimm_names)


def _run_energy(sim: SimSource, clock: Clock, threads: int) -> tuple[dict[str, float], float, float]:
    """Per DRAM sensor, the energy above idle of one run; the measured and the planned (truth) node total."""
    kernel, elements, repeat = "triad", 2_000_000, 5
    clock.t = S // 10
    idle_batch = sim.poll()
    idle_w = {ch: float(idle_batch.samples[ch][1].mean()) for ch in sim.layout.sensors}
    sim.on_run(RunEvent("start", "r", kernel, threads, elements, repeat, clock.t))
    plan = sim.run_plan("r")
    clock.t = S // 10 + plan.duration_ns + S // 2
    batch = sim.poll()
    window_s = len(batch.samples["DDR_AB"][0]) * 0.01
    above = {ch: float(batch.samples[ch][1].sum()) * 0.01 - idle_w[ch] * window_s for ch in sim.layout.sensors}
    measured = sum(float(batch.samples[ch][1].sum()) * 0.01 for ch in sim.layout.sensors)
    duration_s = sum(kernel_traffic_lines(kernel, elements)) * repeat / modelled_line_rate(
        kernel, threads, elements, sim.layout)
    assert plan.duration_ns == pytest.approx(duration_s * 1e9, abs=1)
    d_s = plan.duration_ns * 1e-9
    planned = float((plan.bg_w * d_s + plan.dyn_j + plan.io_j).sum()) + float(plan.idle_w.sum()) * (window_s - d_s)
    return above, measured, planned


def test_ice_lake_run_on_one_socket_leaves_the_other_idle() -> None:
    """28 threads on a 2 × 28-core node fill socket 0: socket 1's DIMMs and package stay idle."""
    clock = Clock()
    sim = quiet_sim(clock, ICE_LAKE_1DPC)
    above, measured, modelled = _run_energy(sim, clock, 28)
    assert sim.run_plan("r").threads == (28, 0)
    busy = [ch for ch in sim.layout.sensors if "A" <= ch[-1] <= "H"]
    idle = [ch for ch in sim.layout.sensors if ch not in busy]
    assert all(above[ch] > 1e-3 for ch in busy), above
    assert all(abs(above[ch]) < 1e-9 for ch in idle), above
    assert measured == pytest.approx(modelled, rel=1e-9)
    plan = sim.run_plan("r")
    assert np.all(np.abs(plan.excess_w[8:]) < 1e-12) and np.all(plan.excess_w[:8] > 0.0)


def test_one_socket_node_run_energy_is_the_truth_plan() -> None:
    """On a 1-socket node every run lands on its 6 channels; the energy equals the sim's truth plan."""
    clock = Clock()
    sim = quiet_sim(clock, ONE_SOCKET)
    above, measured, modelled = _run_energy(sim, clock, 16)
    assert sim.run_plan("r").threads == (16,)
    assert all(v > 1e-3 for v in above.values())
    assert measured == pytest.approx(modelled, rel=1e-9)


def test_sim_takes_a_node_description(tmp_path: Path) -> None:
    """SimSource(node=...) models a configured/detected node."""
    from hdeem_watch.node.overrides import apply_overrides, parse_node_table

    node = apply_overrides(describe_node(tmp_path, None, "none"),
                           parse_node_table({"sockets": 1, "cores_per_socket": 12, "channels_per_socket": 6,
                                             "dimms_per_channel": 1}))
    sim = SimSource(seed=2, node=node)
    assert sim.layout == ONE_SOCKET
