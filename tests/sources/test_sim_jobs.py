"""Opaque jobs on the simulated node and its hidden commands (issue 17): the counters' ground truth.

The sim's energy and its hidden per-DIMM commands come from one plan, so the DRAM energy its sensors
show over a window must be what the hidden commands cost at the DIMMs' hidden currents (plus I/O per
burst); and the commands of a kernel run must be its plan's.
"""

from __future__ import annotations

import numpy as np
import pytest

from hdeem_watch.dram.energy import energy_columns
from hdeem_watch.sim.commands import array_stats
from hdeem_watch.sim.jobs import JOB_KERNEL, job_plan
from hdeem_watch.sources.base import RunEvent
from hdeem_watch.sources.sim import SimSource

SECOND = 1_000_000_000


def exact_sim(now: list[int]) -> SimSource:
    sim = SimSource(seed=5, clock=lambda: now[0], wall_clock=lambda: 0, noise=False, quantum_w=0.0, offsets=False,
                    gains=False, temp_amp_c=0.0, background_plans=False)
    sim.open()
    return sim


def hidden_array(sim: SimSource) -> np.ndarray:
    from hdeem_watch.sim.commands import stats_array

    _t, stats = sim.hidden_commands()
    return np.stack([stats_array(s) for s in stats])


def test_a_jobs_mix_is_hidden_but_reproducible() -> None:
    """The same seed and run id give the same phases; another run id another mix."""
    sim = exact_sim([0])
    node, parts = sim.truth_node, sim.truth_model
    a = job_plan(node, parts.currents(0.0), parts.temperature_c(0.0), "r1", 0, threads=24)
    b = job_plan(node, parts.currents(0.0), parts.temperature_c(0.0), "r1", 0, threads=24)
    c = job_plan(node, parts.currents(0.0), parts.temperature_c(0.0), "r2", 0, threads=24)
    assert [p.kind for p in a.phases] == [p.kind for p in b.phases]
    assert [p.duration_ns for p in a.phases] != [p.duration_ns for p in c.phases]


def test_the_sensors_show_what_the_hidden_commands_cost() -> None:
    """Over a job window the DRAM channels' energy equals the hidden commands priced at the hidden
    currents plus I/O per burst (the noise-free sim); nothing after the stop."""
    now = [SECOND]
    sim = exact_sim(now)
    sim.poll()
    before, e0 = hidden_array(sim), sim.poll().energy_j
    sim.on_run(RunEvent("start", "r1", JOB_KERNEL, 24, 0, 1, now[0]))
    for k in range(2, 16):
        now[0] = k * SECOND
        sim.poll()
    sim.on_run(RunEvent("stop", "r1", JOB_KERNEL, 24, 0, 1, now[0]))
    after = hidden_array(sim)
    now[0] += SECOND // 2
    e1 = sim.poll().energy_j
    measured = sum(e1[c] - e0[c] for c in sim.layout.sensors)
    spec, physics = sim.truth_node.spec, sim.truth_node.physics
    currents = sim.truth_model.currents(0.0)
    priced, idle_tail = 0.0, 0.0
    idle_w = sim.truth_node.idle_power_w(currents, sim.truth_model.temperature_c(0.0))
    for d, delta in enumerate(after - before):
        stats = array_stats(delta)
        linear = energy_columns(spec, stats)
        priced += float(currents[d] @ np.asarray(linear.columns)) + float(linear.constant_j)
        priced += physics.io_read_j * stats.total("rd") + physics.io_write_j * stats.total("wr")
        idle_tail += float(idle_w[d]) * 0.5
    assert measured == pytest.approx(priced + idle_tail, rel=0.005)


def test_a_kernel_runs_hidden_commands_are_its_plans() -> None:
    """Reads, writes and activations over a kernel run are exactly its plan's (after the stop)."""
    now = [SECOND]
    sim = exact_sim(now)
    before = hidden_array(sim)
    sim.on_run(RunEvent("start", "r1", "triad", 12, 1 << 22, 20, now[0]))
    plan = sim.run_plan("r1")
    now[0] += plan.duration_ns + SECOND
    sim.on_run(RunEvent("stop", "r1", "triad", 12, 1 << 22, 20, now[0]))
    sim.poll()
    after = hidden_array(sim) - before
    for d, stats in enumerate(plan.stats):
        got = array_stats(after[d])
        if stats is None:
            assert got.total("rd") == 0
            continue
        for field in ("rd", "wr", "act"):
            assert got.total(field) == pytest.approx(stats.total(field), rel=1e-9)
    assert after.shape[0] == len(sim.layout.dimm_names)
