"""RAPL's energy-unit quantisation of the sim's samples (sim/rapl.py)."""

from __future__ import annotations

import numpy as np
import pytest

from hdeem_watch.sim.rapl import SPR_DRAM_UNIT_J, rapl_samples


def test_rapl_samples_keep_every_joule_and_stay_within_one_unit() -> None:
    """Over calls in chunks, published energy + carry = true energy; each sample within one unit/period;
    a power below one unit per sample publishes zeros until a unit completes (not a steady value)."""
    rng = np.random.default_rng(1)
    power = rng.uniform(2.0, 30.0, 1000)
    period = 0.01
    carry, published = 0.0, []
    for chunk in np.array_split(power, 7):
        out, carry = rapl_samples(chunk, period, SPR_DRAM_UNIT_J, carry)
        published.append(out)
    out = np.concatenate(published)
    assert out.sum() * period + carry == pytest.approx(power.sum() * period, rel=1e-12)
    assert 0.0 <= carry < SPR_DRAM_UNIT_J
    assert np.max(np.abs(out - power)) <= 2 * SPR_DRAM_UNIT_J / period
    assert not np.allclose(out, power, rtol=0, atol=1e-9)  # it is quantised
    tiny, carry = rapl_samples(np.full(10, 0.45 * SPR_DRAM_UNIT_J / period), period, SPR_DRAM_UNIT_J, 0.0)
    assert list(tiny > 0) == [False, False, True, False, True, False, True, False, True, False]
