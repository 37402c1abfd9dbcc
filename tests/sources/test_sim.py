"""The simulated node: rates, no invented bursts, gaps, determinism, socket filling, energy conservation."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from hdeem_watch.sim.model import DIMM_PAIR, kernel_traffic_lines, run_truth_energy_j, socket_shares
from hdeem_watch.sources.base import CHANNELS, DRAM_CHANNELS, RunEvent, Source
from hdeem_watch.sources.registry import make_source
from hdeem_watch.sources.sim import SimSource, modelled_line_rate

S = 1_000_000_000


def quiet_sim(clock, **kw) -> SimSource:
    opts = dict(noise=False, quantum_w=0.0, io_j_per_line=0.0, offsets=False, gains=False, aging_per_h=0.0,
                temp_amp_c=0.0)
    opts.update(kw)
    sim = SimSource(seed=5, clock=clock, wall_clock=lambda: 1_700_000_000 * S, **opts)
    sim.open()
    return sim


def dram_energy(batches, channels=DRAM_CHANNELS) -> float:
    total = 0.0
    for b in batches:
        for ch in channels:
            total += float(b.samples[ch][1].sum()) * 0.01
    return total


def test_protocol_and_rates(fake_clock):
    """The sim is a Source; one second gives 1000 BLADE and 100 of each VR sample, 0.125 W steps."""
    clock = fake_clock()
    sim = SimSource(seed=1, clock=clock, wall_clock=lambda: 10 * S)
    assert isinstance(sim, Source)
    assert [c.name for c in sim.channels()] == list(CHANNELS)
    sim.open()
    clock.t = S
    batch = sim.poll()
    assert len(batch.samples["BLADE"][0]) == 1000
    for ch in CHANNELS[1:]:
        t, p = batch.samples[ch]
        assert len(t) == 100
        assert np.all(np.diff(t) == 10_000_000)
        assert t[-1] == 11 * S
        assert np.allclose(p / 0.125, np.round(p / 0.125))
        assert batch.status[ch] == "ok"
    # cumulative energy is the integral of the published samples
    for ch in CHANNELS:
        dt = 1e-3 if ch == "BLADE" else 1e-2
        assert batch.energy_j[ch] == pytest.approx(batch.samples[ch][1].sum() * dt)


def test_irregular_polls_no_bursts(fake_clock):
    """Polls at irregular times return exactly the samples that became due; none twice, none invented."""
    clock = fake_clock()
    sim = SimSource(seed=2, clock=clock)
    sim.open()
    seen = []
    for dt in (3_000_000, 17_000_000, 1, 250_000_000, 9_999_999, 730_000_000):
        clock.t += dt
        seen.append(sim.poll().samples["DDR_AB"][0])
    t = np.concatenate(seen)
    assert len(t) == clock.t // 10_000_000
    assert np.all(np.diff(t) == 10_000_000)


def test_stall_beyond_buffer_flags_gap_keeps_energy(fake_clock):
    """A poller late beyond the sensor buffer loses the old samples (gap flagged) but not their energy."""
    clock = fake_clock()
    sim = quiet_sim(clock, buffer_s=2.0)
    clock.t = 10 * S
    batch = sim.poll()
    assert len(batch.samples["DDR_AB"][0]) == 200
    assert batch.gaps["DDR_AB"] == 800 and batch.status["DDR_AB"] == "gap"
    idle = float(batch.samples["DDR_AB"][1][0])
    assert batch.energy_j["DDR_AB"] == pytest.approx(idle * 10.0, rel=1e-9)
    clock.t += S // 2
    assert sim.poll().status["DDR_AB"] == "ok"


def test_deterministic_with_seed(fake_clock):
    """The same seed and poll times give identical samples; another seed gives other hidden currents."""
    runs = []
    for seed in (9, 9, 10):
        clock = fake_clock()
        sim = SimSource(seed=seed, clock=clock, wall_clock=lambda: 0)
        sim.open()
        clock.t = S // 3
        runs.append((sim.poll().samples["DDR_CD"][1], sim.truth()["mean_currents_a"]))
    assert np.array_equal(runs[0][0], runs[1][0])
    assert runs[0][1] == runs[1][1]
    assert runs[0][1] != runs[2][1]


def test_truth_ratios_and_drift(fake_clock):
    """Hidden currents are datasheet × ratios within 0.35–0.85, differ per DIMM, and age upwards."""
    clock = fake_clock()
    sim = SimSource(seed=4, clock=clock, temp_amp_c=0.0, aging_per_h=0.01)
    sim.open()
    t0 = sim.truth()
    assert t0["simulated"] is True
    ds = t0["datasheet"]
    for dimm in t0["dimms"].values():
        for name, value in dimm["currents_a"].items():
            if ds[name] > 0:
                assert 0.35 - 1e-12 <= value / ds[name] <= 0.85 + 1e-12
    a, b = (t0["dimms"][k]["currents_a"]["idd0"] for k in ("DIMM_A", "DIMM_E"))
    assert a != b
    clock.t = 3600 * S
    sim.poll()
    later = sim.truth()["mean_currents_a"]["idd0"]
    assert later == pytest.approx(t0["mean_currents_a"]["idd0"] * 1.01, rel=1e-9)


def test_line_rate_saturates():
    """Bandwidth grows with threads, saturates per socket, doubles with socket 1; no traffic = 0."""
    rates = [modelled_line_rate("read", n) * 64 / 1e9 for n in (1, 2, 6, 12, 13, 24)]
    assert rates[0] == pytest.approx(7.0, rel=0.01)
    assert all(b >= a for a, b in itertools.pairwise(rates))
    assert 40 < rates[3] < 60
    assert 2 * rates[3] == pytest.approx(rates[5], rel=0.03)  # the socket model at half the arrays
    assert modelled_line_rate("triad", 12) < modelled_line_rate("read", 12)
    assert modelled_line_rate("idle", 12) == 0.0
    assert socket_shares(12) == (1.0, 0.0) and socket_shares(16) == (0.75, 0.25)


@pytest.mark.parametrize(("kernel", "threads"), [("read", 24), ("triad", 24), ("copy", 12), ("add", 18)])
def test_line_rate_within_the_controller_capacity(kernel, threads):
    """A run never moves more lines/s on a socket than the controller model of its channels can serve."""
    from hdeem_watch.dram.node import cycles_per_line, lines_of
    from hdeem_watch.sim.model import TOPOLOGY, default_model

    model = default_model()
    elements = 1 << 22
    groups = model.node_stats(kernel, elements, threads, 1)
    rate = modelled_line_rate(kernel, threads, elements)
    total = sum(lines_of(stats) * n for stats, n in groups)
    for stats, n in groups:
        if lines_of(stats) == 0:
            continue
        socket_rate = rate * lines_of(stats) * n / total
        capacity = n / (cycles_per_line(stats) * model.tck_s)
        assert socket_rate <= capacity * (1 + 1e-9)
    assert len(groups) == TOPOLOGY.sockets


def _power_during_run(threads: int, clock) -> dict[str, float]:
    sim = quiet_sim(clock)
    clock.t = S
    idle = {ch: float(np.mean(v[1])) for ch, v in sim.poll().samples.items()}
    sim.on_run(RunEvent("start", "r", "read", threads, 400_000_000, 50, clock.t))
    sim.run_plan("r", timeout_s=120)
    clock.t += S // 2
    busy = {ch: float(np.mean(v[1])) for ch, v in sim.poll().samples.items()}
    return {ch: busy[ch] - idle[ch] for ch in CHANNELS}


def test_threads_fill_socket0_first(fake_clock):
    """≤ 12 threads load only socket 0's DIMM pairs and CPU0; beyond 12 socket 1 gets the extra threads' traffic."""
    d12 = _power_during_run(12, fake_clock())
    assert d12["DDR_AB"] > 0.2 and d12["DDR_CD"] > 0.2
    assert d12["DDR_EF"] == pytest.approx(0.0, abs=1e-9) and d12["DDR_GH"] == pytest.approx(0.0, abs=1e-9)
    assert d12["CPU0"] > 10 and d12["CPU1"] == pytest.approx(0.0, abs=1e-9)
    d24 = _power_during_run(24, fake_clock())
    assert d24["DDR_EF"] > 0.2 and d24["CPU1"] > 10
    assert d24["BLADE"] > d12["BLADE"]


def plan_energy_j(plan, until_ns: int | None = None) -> float:
    """The plan's DRAM energy over its traffic (all of its commands and I/O; background up to ``until_ns``)."""
    end = plan.duration_ns if until_ns is None else min(plan.duration_ns, until_ns - plan.t0_ns)
    return float((plan.bg_w * end * 1e-9 + plan.dyn_j + plan.io_j).sum())


@pytest.mark.parametrize("threads", [8, 20])
def test_completed_run_energy_equals_its_plan(threads, fake_clock):
    """A run's DRAM samples hold exactly its plan's energy (background, commands, I/O) plus idle power around it."""
    clock = fake_clock()
    sim = quiet_sim(clock, io_j_per_line=0.5e-9)
    kernel, elements, repeat = "triad", 2_000_000, 20
    clock.t = S // 10
    sim.poll()
    sim.on_run(RunEvent("start", "r", kernel, threads, elements, repeat, clock.t))
    plan = sim.run_plan("r", timeout_s=120)
    lines = sum(kernel_traffic_lines(kernel, elements)) * repeat
    duration_s = lines / modelled_line_rate(kernel, threads, elements)
    assert plan.duration_ns == pytest.approx(duration_s * 1e9, abs=1)
    assert float(plan.io_j.sum()) > 0
    # poll well after the end of traffic: the batch holds the whole run plus idle time
    clock.t = S // 10 + plan.duration_ns + S // 2
    batch = sim.poll()
    measured = dram_energy([batch])
    window_s = (batch.samples["DDR_AB"][0][-1] - batch.samples["DDR_AB"][0][0] + 10_000_000) * 1e-9
    idle_w = float(plan.idle_w.sum())
    assert measured == pytest.approx(plan_energy_j(plan) + idle_w * (window_s - plan.duration_ns * 1e-9), rel=1e-9)


def test_early_stop_conserves_energy(fake_clock):
    """Stopped before its traffic is done, the rest of the run's command energy comes right at the stop."""
    clock = fake_clock()
    sim = quiet_sim(clock)
    kernel, elements, threads, repeat = "copy", 4_000_000, 24, 40
    sim.on_run(RunEvent("start", "r", kernel, threads, elements, repeat, 0))
    plan = sim.run_plan("r", timeout_s=120)
    stop = (plan.duration_ns // 2) // 10_000_000 * 10_000_000
    clock.t = stop - 30_000_000
    first = sim.poll()
    sim.on_run(RunEvent("stop", "r", kernel, threads, elements, repeat, stop))
    clock.t = stop + 10_000_000
    second = sim.poll()
    measured = dram_energy([first, second]) - float(plan.idle_w.sum()) * 0.01  # one sample after the stop
    assert measured == pytest.approx(plan_energy_j(plan, stop), rel=1e-9)
    # after the stop the node is idle again
    clock.t += S // 10
    later = sim.poll()
    assert float(later.samples["DDR_AB"][1].mean()) == pytest.approx(float(plan.idle_w[:2].sum()))


def test_run_energy_is_drampower_of_the_sims_own_statistics(fake_clock):
    """The truth prices the sim's own per-DIMM statistics with DRAMPower's energies at each DIMM's currents."""
    from hdeem_watch.dram.energy import core_energy

    clock = fake_clock()
    sim = quiet_sim(clock)
    kernel, elements, threads, repeat = "scale", 3_000_000, 18, 10
    sim.on_run(RunEvent("start", "r", kernel, threads, elements, repeat, 0))
    plan = sim.run_plan("r", timeout_s=120)
    d_s = plan.duration_ns * 1e-9
    currents = sim.truth_model.currents(0.0)
    stats = sim.truth_node.dimm_stats(kernel, elements, threads, repeat, d_s, sim.truth_model.temperature_c(0.0))
    model = sim.model
    for d, dimm_stats in enumerate(stats):
        assert dimm_stats is not None   # 18 threads: both sockets
        spec = model.spec.with_currents(dict(zip(model.names, map(float, currents[d]), strict=True)))
        core = core_energy(spec, dimm_stats).core_j
        assert plan.bg_w[d] * d_s + plan.dyn_j[d] == pytest.approx(core, rel=1e-7)
    socket0 = stats[0]
    socket1 = stats[4]
    assert socket0 is not None and socket1 is not None
    assert socket0.total("rd") == pytest.approx(2 * socket1.total("rd"), rel=0.05)  # 12 vs 6 threads


def test_speed_and_factory(fake_clock):
    """At speed 10 one clock second holds ten sim seconds of samples; make_source('sim') builds it."""
    clock = fake_clock()
    sim = make_source("sim", seed=1, clock=clock, speed=10.0, wall_clock=lambda: 0)
    sim.open()
    clock.t = S
    assert len(sim.poll().samples["DDR_GH"][0]) == 1000
    assert DIMM_PAIR.count("DDR_AB") == 2


def test_background_plan_holds_samples_back_without_loss(monkeypatch, fake_clock):
    """While a run's plan is computed in the background, samples after its start wait; none are lost."""
    import threading

    gate = threading.Event()
    clock = fake_clock()
    sim = quiet_sim(clock)
    real_plan = sim.truth_node.plan

    def slow_plan(*args):
        gate.wait(30)
        return real_plan(*args)

    monkeypatch.setattr(sim.truth_node, "plan", slow_plan)
    clock.t = S // 10
    sim.poll()
    sim.on_run(RunEvent("start", "r", "add", 4, 1_000_000, 10, clock.t))   # returns at once
    clock.t = S // 2
    held = sim.poll()
    assert len(held.samples["DDR_AB"][0]) == 0 and len(held.samples["CPU0"][0]) == 0
    sim.on_run(RunEvent("stop", "r", "add", 4, 1_000_000, 10, clock.t))     # a stop while pending is kept
    gate.set()
    plan = sim.run_plan("r", timeout_s=30)
    assert plan.cpu_end_ns == S // 2
    clock.t = S
    after = sim.poll()
    t = after.samples["DDR_AB"][0]
    assert len(t) == 90 and t[0] == 1_700_000_000 * S + 110_000_000   # 0.1 s .. 1.0 s, nothing lost


def test_datasheet_model_overestimates_the_sim_node():
    """On kernel runs the datasheet model overestimates the sim's DRAM energy 1.3–2.5× (field: ~2×)."""
    from hdeem_watch.sim.currents import PartCurrents
    from hdeem_watch.sim.plan import TruthNode

    ratios = []
    for seed in (0, 1, 2):
        node = TruthNode(seed)
        model = node.model
        parts = PartCurrents(model.names, model.datasheet, seed, pairs=node.layout.dimm_sensor)
        for kernel, threads in (("read", 24), ("triad", 12), ("copy", 4)):
            plan = node.plan(parts.currents(0.0), parts.temperature_c(0.0), "r", 0, kernel, 1 << 22, threads, 20)
            d_s = plan.duration_ns * 1e-9
            sim_j = float((plan.bg_w * d_s + plan.dyn_j + plan.io_j).sum())
            datasheet = np.broadcast_to(model.datasheet, (8, len(model.names)))
            ds_j = run_truth_energy_j(model, datasheet, kernel, 1 << 22, threads, 20, d_s)
            ratios.append(ds_j / sim_j)
    assert 1.3 < float(np.mean(ratios)) < 2.5, ratios
    assert min(ratios) > 1.1


def test_a_start_behind_the_published_samples_keeps_the_runs_energy(fake_clock):
    """A start announced for a time whose samples were already published (a sped-up sim between polls) runs
    its traffic from that time: the energy those idle samples could not show comes in the next sample."""
    clock = fake_clock()
    sim = quiet_sim(clock, io_j_per_line=0.5e-9)
    clock.t = S
    before = sim.poll()
    sim.on_run(RunEvent("start", "r", "read", 24, 1 << 22, 40, S // 2))   # 0.5 s: already published
    plan = sim.run_plan("r", timeout_s=120)
    assert plan.t0_ns == S // 2 and plan.duration_ns > 0
    clock.t = S // 2 + plan.duration_ns + S
    after = sim.poll()
    total_s = (clock.t // 10_000_000) * 0.01   # the last whole sample
    expected = float(plan.idle_w.sum()) * total_s + float(plan.excess_w.sum()) * plan.duration_ns * 1e-9
    assert dram_energy([before, after]) == pytest.approx(expected, rel=1e-9)


def test_a_stopped_run_owes_no_spike(fake_clock):
    """Stopped at a quarter of its traffic, the rest of a run's energy comes within what a pair can
    draw: no sample of a DIMM pair above its physical maximum or below 0 W, BLADE's rise no larger than
    all DIMMs' maximum, and every joule still arrives (issue #28: 133 W on DDR_AB before)."""
    from hdeem_watch.sim.power import dimm_peak_w

    clock = fake_clock()
    sim = quiet_sim(clock)
    kernel, elements, threads, repeat = "copy", 4_000_000, 24, 40
    sim.on_run(RunEvent("start", "r", kernel, threads, elements, repeat, 0))
    plan = sim.run_plan("r", timeout_s=120)
    stop = (plan.duration_ns // 4) // 10_000_000 * 10_000_000
    clock.t = stop
    first = sim.poll()
    sim.on_run(RunEvent("stop", "r", kernel, threads, elements, repeat, stop))
    clock.t = stop + 20 * S
    second = sim.poll()
    peak = dimm_peak_w(sim.truth_node.spec)
    for pair in DRAM_CHANNELS:
        values = np.concatenate([b.samples[pair][1] for b in (first, second)])
        assert values.min() >= 0.0 and values.max() <= 2 * peak + 1e-9, (pair, values.max())
    blade = second.samples["BLADE"][1]
    assert blade.max() - np.median(blade) <= 8 * peak + 1e-9
    idle_after = float(plan.idle_w.sum()) * 20.0
    assert dram_energy([first, second]) == pytest.approx(plan_energy_j(plan, stop) + idle_after, rel=1e-6)
