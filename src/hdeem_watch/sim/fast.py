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
* :func:`idle_block` generates an idle group's samples *ahead* (a few seconds of sim time), with
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

from collections.abc import Callable
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


#: Blocks up to this many columns keep their energies as plain floats too (1 s at 1000 Sa/s, ×8).
LIST_COLUMNS = 8192


@dataclass(frozen=True)
class IdleBlock:
    """Samples of one group of channels (same grid) generated ahead while the node is idle.

    Attributes:
        k_first: sample index (sim time / period) of column 0.
        k_last: sample index of the last column.
        t_wall_ns: sample timestamps (int64, one per column).
        rows: per channel, its samples (W; views of one 2-D array).
        energy_j: per channel (rows), its cumulative energy after each column (J).
        energy_rows: the same as plain floats (read by index without a numpy call), for blocks of
            at most :data:`LIST_COLUMNS` columns (a sped-up sim's long blocks read ``energy_j``).
    """

    k_first: int
    k_last: int
    t_wall_ns: np.ndarray
    rows: tuple[np.ndarray, ...]
    energy_j: np.ndarray
    energy_rows: list[list[float]] | None

    def energies_after(self, i: int) -> list[float]:
        """Every channel's cumulative energy after column ``i`` (J)."""
        if self.energy_rows is not None:
            return [row[i] for row in self.energy_rows]
        return list(self.energy_j[:, i].tolist())


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
    return IdleBlock(k_first, k_last, t_wall, tuple(power), energy, energy.tolist() if n <= LIST_COLUMNS else None)


class IdleBlocks:
    """The idle node's fast path: per group of channels on the same grid, a block of samples generated ahead.

    Args:
        groups: per group ``(period ns, channel names, noise σ per channel as a (k, 1) column)``.
        noise: the noise bank (None = no noise).
        quantum_w: quantisation step (0 = none).
        block_ns: how far (sim ns) past the poll a new block reaches.
        buffer_k: per channel, the samples the sensor buffer holds (a longer stretch is not served).
    """

    def __init__(self, groups: list[tuple[int, tuple[str, ...], np.ndarray]], noise: NoiseBank | None,
                 quantum_w: float, block_ns: int, buffer_k: dict[str, int]) -> None:
        self.groups = groups
        self.noise = noise
        self.quantum_w = quantum_w
        self.block_ns = block_ns
        self.buffer_k = buffer_k
        self.blocks: list[IdleBlock | None] = [None] * len(groups)

    def poll(self, sim_now: int, t0_wall_ns: int, next_k: dict[str, int], energy_j: dict[str, float],
             samples: dict[str, tuple[np.ndarray, np.ndarray]], flat_w: Callable[[int], dict[str, float]]) -> None:
        """Serve every group's samples due by ``sim_now`` from its block (in place: ``next_k``, ``energy_j``, ``samples``).

        A group whose poll reaches past its block gets a new block from its next sample to
        ``block_ns`` past ``sim_now`` (``flat_w(sim_now)``: every channel's noise-free idle power);
        a group that lost samples to the sensor buffer is dropped and left to the caller.
        """
        for g, (period, names, _sigma) in enumerate(self.groups):
            first = names[0]
            k0, k1 = next_k[first], sim_now // period
            if k1 - k0 + 1 > self.buffer_k[first]:
                self.drop(g, next_k)
                continue
            block = self.blocks[g]
            if block is None or k1 > block.k_last:
                self.drop(g, next_k)
                period, names, sigma_col = self.groups[g]
                k_last = max(k1, (sim_now + self.block_ns) // period)
                noise = self.noise.take_rows(names, sigma_col, k_last - k0 + 1) if self.noise is not None else None
                flat = flat_w(sim_now)
                block = self.blocks[g] = idle_block(k0, k_last, period, t0_wall_ns, np.array([[flat[n]] for n in names]),
                                                    noise, self.quantum_w, np.array([energy_j[n] for n in names]))
            i0, i1 = k0 - block.k_first, k1 + 1 - block.k_first
            t_wall = block.t_wall_ns[i0:i1]
            for name, row in zip(names, block.rows):
                samples[name] = (t_wall, row[i0:i1])
            if i1 > i0:
                for name, total in zip(names, block.energies_after(i1 - 1)):
                    energy_j[name] = total
                    next_k[name] = k1 + 1

    def drop(self, g: int, next_k: dict[str, int]) -> None:
        """Forget group ``g``'s block; its unpublished samples' noise goes back to the bank."""
        block = self.blocks[g]
        if block is None:
            return
        self.blocks[g] = None
        names = self.groups[g][1]
        unpublished = block.k_last - next_k[names[0]] + 1
        if self.noise is not None and unpublished > 0:
            for name in names:
                self.noise.rewind(name, unpublished)

    def drop_all(self, next_k: dict[str, int]) -> None:
        """Forget every block (the node is no longer idle, or the sim closes)."""
        for g in range(len(self.groups)):
            self.drop(g, next_k)

    @property
    def any(self) -> bool:
        """Whether some group has a block."""
        return any(block is not None for block in self.blocks)
