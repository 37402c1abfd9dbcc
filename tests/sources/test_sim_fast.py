"""The simulated node's hot path (idle blocks generated ahead) gives the samples of its general path."""

from __future__ import annotations

import numpy as np
import pytest

from hdeem_watch.sim.fast import NoiseBank
from hdeem_watch.sources.base import RunEvent
from hdeem_watch.sources.sim import SimSource

S = 1_000_000_000


def _polls(fast: bool, **options) -> list:
    """Irregular polls of one sim (stalls within and beyond the sensor buffer, a run in between)."""
    t = [0]
    sim = SimSource(seed=11, clock=lambda: t[0], wall_clock=lambda: 1_700_000_000 * S, background_plans=False,
                    **options)
    if not fast:
        sim._idle.poll = lambda *args: None  # type: ignore[method-assign]  # every channel on the general path
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


@pytest.mark.parametrize("options", [{}, {"noise": False}, {"quantum_w": 0.0, "offsets": False}, {"block_s": 0.0}])
def test_idle_blocks_are_identical_to_the_general_path(options) -> None:
    """Idle samples generated ahead in blocks and sliced per poll equal, bit for bit, the per-channel general
    path computed at each poll (samples, timestamps, status, gaps; cumulative energies to rounding), before,
    during and after a run (whose start drops a block's unpublished rest and gives its noise back) — with the
    hidden currents' drift off, the one thing a block evaluates at another time (its start, not each poll)."""
    options = {"aging_per_h": 0.0, "temp_amp_c": 0.0, **options}
    fast, slow = _polls(True, **options), _polls(False, **options)
    assert sum(len(t) for b in fast for t, _ in b.samples.values()) > 100_000
    for a, b in zip(fast, slow, strict=True):
        assert a.status == b.status and a.gaps == b.gaps
        assert a.energy_j == pytest.approx(b.energy_j, rel=1e-12, abs=1e-12)
        for name, (t_ns, power_w) in a.samples.items():
            assert np.array_equal(t_ns, b.samples[name][0])
            assert np.array_equal(power_w, b.samples[name][1])


def test_idle_blocks_with_drift_stay_within_a_step_of_the_general_path() -> None:
    """With the currents' aging and temperature drift on, a block's samples (drift evaluated at the block's
    start, ≤ 1 sim-s earlier) are within one 0.125 W step of the general path's, so the energies agree to 1e-4
    (a few samples a step apart)."""
    fast, slow = _polls(True), _polls(False)
    for a, b in zip(fast, slow, strict=True):
        assert a.status == b.status and a.gaps == b.gaps
        assert a.energy_j == pytest.approx(b.energy_j, rel=1e-4)
        for name, (t_ns, power_w) in a.samples.items():
            assert np.array_equal(t_ns, b.samples[name][0])
            assert np.all(np.abs(power_w - b.samples[name][1]) <= 0.125 + 1e-9)


def test_noise_bank_draws_the_same_values_as_one_call_per_poll() -> None:
    """Noise drawn in blocks and handed out in slices equals one normal(0, σ, n) call per request."""
    bank = NoiseBank({"a": np.random.default_rng(3), "b": np.random.default_rng(5)}, {"a": 0.8, "b": 0.05}, block=16)
    ref = {"a": np.random.default_rng(3), "b": np.random.default_rng(5)}
    for n in (0, 5, 16, 1, 40, 3):
        assert np.array_equal(bank.take("a", n), ref["a"].normal(0.0, 0.8, size=n))
        rows = bank.take_rows(("a", "b"), np.array([[0.8], [0.05]]), n)
        assert np.array_equal(rows[0], ref["a"].normal(0.0, 0.8, size=n))
        assert np.array_equal(rows[1], ref["b"].normal(0.0, 0.05, size=n))


def test_noise_bank_rewind_gives_the_same_values_again() -> None:
    """Values given back with rewind are handed out again, in order; more than the last take cannot be given back."""
    bank = NoiseBank({"a": np.random.default_rng(3)}, {"a": 1.0}, block=8)
    ref = np.random.default_rng(3).normal(0.0, 1.0, size=23)
    first = bank.take("a", 5)
    block = bank.take("a", 12)          # refills: the buffer now starts at this take
    bank.rewind("a", 7)
    again = bank.take("a", 13)
    assert np.array_equal(np.concatenate((first, block[:5], again)), ref)
    with pytest.raises(ValueError):
        bank.rewind("a", 14)
