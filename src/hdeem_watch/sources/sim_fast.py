"""The simulated node's hot path: block-drawn noise and the idle node's samples generated ahead in blocks.

The sim polls 25 times a second inside the daemon, so each poll's cost is mostly per-call overhead
(a numpy call on a cold cache costs several µs whatever its size). Three things keep it small:

* :class:`NoiseBank` draws each channel's standard-normal noise from the channel's own generator in
  blocks and hands out slices; the values are exactly those of one ``normal(0, σ, n)`` call per
  poll (numpy's generators draw normals one after another, whatever the call sizes). A slice that
  was taken but not used can be given back (:meth:`NoiseBank.rewind`).
* :func:`idle_rows` computes the samples of several channels with the same grid (the six 100 Sa/s
  channels) as one 2-D array while the node is idle (its noise-free power is then one number per
  channel), with the same float operations in the same order as the general path.
* :func:`idle_block` generates an idle group's samples *ahead* (about a second of sim time), with
  their timestamps and cumulative energies, so most polls only slice what became due
  (:class:`IdleBlock`). The sim drops the unpublished part of a block (and rewinds its noise) as
  soon as the node stops being idle, so the power still responds to runs at once.

Example:
    >>> import numpy as np
    >>> bank = NoiseBank({"x": np.random.default_rng(1)}, {"x": 2.0}, block=4)
    >>> a = bank.take("x", 3); b = bank.take("x", 5)
    >>> bool(np.array_equal(np.concatenate((a, b)), np.random.default_rng(1).normal(0.0, 2.0, size=8)))
    True
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


class NoiseBank:
    """Gaussian noise per channel, drawn from each channel's generator in blocks.

    Args:
        rngs: one generator per channel (the bank owns them from now on).
        sigma_w: the noise's standard deviation per channel (W).
        block: standard normals drawn per refill (at least the request).
    """

    def __init__(self, rngs: dict[str, np.random.Generator], sigma_w: dict[str, float], *, block: int = 4096) -> None:
        self._rngs = rngs
        self._sigma = {name: float(sigma_w[name]) for name in rngs}
        self._block = max(1, int(block))
        self._buf = {name: np.empty(0) for name in rngs}
        self._pos = dict.fromkeys(rngs, 0)

    def _z(self, name: str, n: int) -> np.ndarray:
        """The next ``n`` standard normals of ``name`` (a view)."""
        buf, pos = self._buf[name], self._pos[name]
        if pos + n > buf.size:
            rest = buf[pos:]
            buf = self._buf[name] = np.concatenate((rest, self._rngs[name].standard_normal(max(self._block,
                                                                                              n - rest.size))))
            pos = 0
        self._pos[name] = pos + n
        return buf[pos:pos + n]

    def rewind(self, name: str, n: int) -> None:
        """Give back the last ``n`` values taken from ``name`` (at most those of its latest take)."""
        pos = self._pos[name] - int(n)
        if pos < 0:
            raise ValueError(f"noise {name}: cannot rewind {n} values (only {self._pos[name]} kept)")
        self._pos[name] = pos

    def take(self, name: str, n: int) -> np.ndarray:
        """The next ``n`` noise values of ``name`` (W, a new array)."""
        return self._sigma[name] * self._z(name, n)

    def take_rows(self, names: tuple[str, ...], sigma_col: np.ndarray, n: int) -> np.ndarray:
        """The next ``n`` noise values of each of ``names`` as rows (W); ``sigma_col`` = their σ, shape (k, 1)."""
        return sigma_col * np.stack([self._z(name, n) for name in names])


def quantise(power_w: np.ndarray, quantum_w: float) -> np.ndarray:
    """Round to the sensor's steps and clip at 0 W (in place where possible)."""
    if quantum_w > 0:
        power_w = np.round(power_w / quantum_w) * quantum_w
    return np.maximum(power_w, 0.0, out=power_w)


def idle_rows(base_w: np.ndarray, noise: np.ndarray | None, quantum_w: float, n: int) -> np.ndarray:
    """Samples of k channels with constant noise-free power ``base_w`` (shape (k, 1)) over n samples.

    Args:
        base_w: noise-free power per channel, shape (k, 1).
        noise: noise per channel and sample, shape (k, n), or None for none.
        quantum_w: quantisation step (0 = none).
        n: samples per channel.

    Returns:
        Shape (k, n): ``base + noise``, quantised, clipped at 0 — each row exactly what the general
        path computes for its channel.
    """
    power = base_w + noise if noise is not None else np.repeat(base_w, n, axis=1)
    return quantise(power, quantum_w)


@dataclass(frozen=True)
class IdleBlock:
    """Samples of one group of channels (same grid) generated ahead while the node is idle.

    Attributes:
        k_first: sample index (sim time / period) of column 0.
        k_last: sample index of the last column.
        t_wall_ns: sample timestamps (int64, one per column).
        rows: per channel, its samples (W; views of one 2-D array).
        energy_j: per column, every channel's cumulative energy after it (J; plain floats, read by
            index without a numpy call).
    """

    k_first: int
    k_last: int
    t_wall_ns: np.ndarray
    rows: tuple[np.ndarray, ...]
    energy_j: list[list[float]]


def idle_block(k_first: int, k_last: int, period_ns: int, t0_wall_ns: int, base_w: np.ndarray,
               noise: np.ndarray | None, quantum_w: float, start_energy_j: np.ndarray) -> IdleBlock:
    """The samples ``k_first..k_last`` of k idle channels with constant noise-free power.

    Args:
        k_first: first sample index (its interval ends at ``k_first · period``).
        k_last: last sample index.
        period_ns: the channels' sample period.
        t0_wall_ns: wall-clock time of sim time 0.
        base_w: noise-free power per channel, shape (k, 1).
        noise: noise per channel and sample, shape (k, n), or None.
        quantum_w: quantisation step (0 = none).
        start_energy_j: each channel's cumulative energy before ``k_first``, shape (k,).
    """
    n = k_last - k_first + 1
    power = idle_rows(base_w, noise, quantum_w, n)
    t_wall = np.arange(k_first * period_ns + t0_wall_ns, k_last * period_ns + t0_wall_ns + 1, period_ns,
                       dtype=np.int64)
    energy = np.cumsum(power, axis=1)
    energy *= period_ns * 1e-9
    energy += start_energy_j[:, None]
    return IdleBlock(k_first, k_last, t_wall, tuple(power), energy.T.tolist())
