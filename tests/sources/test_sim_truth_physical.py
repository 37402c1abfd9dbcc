"""The simulated node's hidden truth is physically possible (issue 15): the memspec check passes."""

from __future__ import annotations

import numpy as np
import pytest

from hdeem_watch.dram.memspec_check import physical_violations
from hdeem_watch.sim.currents import truth_parts
from hdeem_watch.sim.model import DIMMS, TruthModel, default_model
from hdeem_watch.sim.plan import TruthNode


@pytest.mark.parametrize("seed", range(12))
def test_truth_passes_the_physical_check(seed: int) -> None:
    """Every DIMM's true currents, at any temperature and age (a pair aging too), give no negative command energy."""
    model = default_model()
    truth = TruthModel(model.names, model.datasheet, seed, temp_amp_c=15.0, aging_per_h=0.05, age={"P1": 0.30},
                       ambient_c=70.0)
    for t_s in (0.0, 900.0, 1800.0, 2700.0, 36_000.0):
        currents = truth.currents(t_s)
        for d in range(len(DIMMS)):
            spec = model.spec.with_currents(dict(zip(model.names, map(float, currents[d]), strict=True)))
            assert physical_violations(spec) == [], (seed, t_s, DIMMS[d])


def test_independent_ratios_would_break_the_order() -> None:
    """The failure this guards: datasheet × independent ratios put IDD3N below IDD2N for some seed."""
    model = default_model()
    names = model.names
    broken = 0
    for seed in range(12):
        truth = TruthModel(names, model.datasheet, seed)
        plain = model.datasheet[None, :] * truth.ratio
        broken += int(np.any(plain[:, names.index("idd3n")] < plain[:, names.index("idd2n")]))
        fixed = truth.currents(0.0)
        assert np.all(fixed[:, names.index("idd3n")] >= fixed[:, names.index("idd2n")])
        assert np.all(fixed[:, names.index("idd0")] >= fixed[:, names.index("idd3n")])
    assert broken > 0


def test_truth_parts_keeps_ratios_in_range() -> None:
    """Each truth current is a weighted mean of ratios × datasheet: truth/datasheet stays in range."""
    model = default_model()
    rng = np.random.default_rng(3)
    ratio = rng.uniform(0.35, 0.85, size=(8, len(model.names)))
    floor, inc = truth_parts(model.names, model.datasheet, ratio, ("idd2n", "idd3n"))
    assert np.all(floor >= 0) and np.all(inc >= -1e-15)
    total = floor + inc
    ok = model.datasheet > 0
    share = total[:, ok] / model.datasheet[ok]
    assert np.all(share >= 0.35 - 1e-12) and np.all(share <= 0.85 + 1e-12)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize(("kernel", "threads"), [("read", 1), ("copy", 2), ("triad", 4), ("read", 24)])
def test_runs_never_draw_below_idle(seed: int, kernel: str, threads: int) -> None:
    """DDR "above baseline" is never negative: a run's per-DIMM power is at least the idle power."""
    node = TruthNode(seed)
    model = node.model
    truth = TruthModel(model.names, model.datasheet, seed, pairs=node.layout.dimm_sensor)
    currents, temps = truth.currents(0.0), truth.temperature_c(0.0)
    plan = node.plan(currents, temps, "r", 0, kernel, 1 << 20, threads, 5)
    assert plan.duration_ns > 0
    assert np.all(plan.excess_w >= -1e-12), plan.excess_w
    assert np.all(node.idle_power_w(currents, temps) > 0)
