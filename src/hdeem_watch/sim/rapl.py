"""RAPL's energy quantisation for the simulated node: samples as a DRAM energy counter shows them.

HDEEM publishes power in 0.125 W steps; RAPL publishes a cumulative energy counter that counts in
whole energy units (Sapphire Rapids' DRAM domain: 2⁻¹⁶ J ≈ 15.3 µJ, a fixed unit that does not
follow ``MSR_RAPL_POWER_UNIT``), and :class:`~hdeem_watch.sources.rapl.RaplSource` publishes
``ΔE/Δt`` between reads. :func:`rapl_samples` turns the sim's true mean-power samples into those:
the energy below one unit stays in the counter (``carry_j``) until it completes a unit, so no
energy is lost over a run, and each sample is within ``unit_j / period_s`` of the true power.

Example:
    >>> import numpy as np
    >>> out, carry = rapl_samples(np.array([1.0, 1.0]), 0.01, 0.003, 0.0)
    >>> [round(float(w), 6) for w in out], round(carry, 6)
    ([0.9, 0.9], 0.002)
"""

from __future__ import annotations

import numpy as np

#: Sapphire Rapids' DRAM energy unit (J): 2⁻¹⁶ J ≈ 15.3 µJ.
SPR_DRAM_UNIT_J = 2.0 ** -16


def rapl_samples(power_w: np.ndarray, period_s: float, unit_j: float, carry_j: float) -> tuple[np.ndarray, float]:
    """Mean-power samples as ``ΔE/Δt`` of a counter counting whole ``unit_j``; and the new carry.

    Args:
        power_w: true mean power of consecutive intervals of ``period_s`` (W).
        period_s: the sample interval (s, > 0).
        unit_j: the counter's energy unit (J, > 0).
        carry_j: energy counted by no unit yet from the previous call (J, ``0 <= carry_j < unit_j``).

    Returns:
        The published samples (W) and the energy left below one unit after the last one.
    """
    power = np.asarray(power_w, dtype=float)
    if power.size == 0:
        return power.copy(), float(carry_j)
    cumulative = float(carry_j) + np.cumsum(power * period_s)
    counted = np.floor(cumulative / unit_j) * unit_j
    previous = np.concatenate(([0.0], counted[:-1]))
    return (counted - previous) / period_s, float(cumulative[-1] - counted[-1])
