"""The simulated node's hot path gives exactly the samples of its general path."""

from __future__ import annotations

import numpy as np
import pytest

from hdeem_watch.sources.base import RunEvent
from hdeem_watch.sources.sim import SimSource
from hdeem_watch.sources.sim_fast import NoiseBank

S = 1_000_000_000


def _polls(fast: bool, **options) -> list:
    """Irregular polls of one sim (stalls within and beyond the sensor buffer, a run in between)."""
    t = [0]
    sim = SimSource(seed=11, clock=lambda: t[0], wall_clock=lambda: 1_700_000_000 * S, background_plans=False,
                    **options)
    if not fast:
        sim._poll_idle = lambda *args: None  # type: ignore[method-assign]  # every channel on the general path
    sim.open()
    rng = np.random.default_rng(4)
    batches = []
    for i in range(240):
        t[0] += int(rng.integers(1, 60_000_000))
        if i == 60:
            sim.on_run(RunEvent("start", "r1", "triad", 24, 4_000_000, 3, t[0]))
        if i == 90:
            sim.on_run(RunEvent("stop", "r1", "triad", 24, 4_000_000, 3, t[0]))
        if i == 150:
            t[0] += 70 * S   # beyond the 60 s buffer: samples lost
        if i == 200:
            t[0] += 20 * S   # a long batch within the buffer
        batches.append(sim.poll())
    return batches


@pytest.mark.parametrize("options", [{}, {"noise": False}, {"quantum_w": 0.0, "offsets": False}])
def test_fast_idle_path_is_identical_to_the_general_path(options) -> None:
    """Idle polls computed as one array per channel group equal, bit for bit, the per-channel general path
    (samples, timestamps, cumulative energies, status and gaps), before, during and after a run."""
    fast, slow = _polls(True, **options), _polls(False, **options)
    assert sum(len(t) for b in fast for t, _ in b.samples.values()) > 100_000
    for a, b in zip(fast, slow, strict=True):
        assert a.energy_j == b.energy_j and a.status == b.status and a.gaps == b.gaps
        for name, (t_ns, power_w) in a.samples.items():
            assert np.array_equal(t_ns, b.samples[name][0])
            assert np.array_equal(power_w, b.samples[name][1])


def test_noise_bank_draws_the_same_values_as_one_call_per_poll() -> None:
    """Noise drawn in blocks and handed out in slices equals one normal(0, σ, n) call per request."""
    bank = NoiseBank({"a": np.random.default_rng(3), "b": np.random.default_rng(5)}, {"a": 0.8, "b": 0.05}, block=16)
    ref = {"a": np.random.default_rng(3), "b": np.random.default_rng(5)}
    for n in (0, 5, 16, 1, 40, 3):
        assert np.array_equal(bank.take("a", n), ref["a"].normal(0.0, 0.8, size=n))
        rows = bank.take_rows(("a", "b"), np.array([[0.8], [0.05]]), n)
        assert np.array_equal(rows[0], ref["a"].normal(0.0, 0.8, size=n))
        assert np.array_equal(rows[1], ref["b"].normal(0.0, 0.05, size=n))
