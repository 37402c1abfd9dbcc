"""The simulated node's own memory controller view: page placement, address hash, row hits per channel.

The daemon's model assumes each array is physically contiguous (1, 2 and 3 GiB), split evenly over
a socket's channels, and decoded as ``RoBaRaCoCh`` with an XOR-fold bank hash
(:func:`hdeem_watch.dram.kernels.kernel_stats`). The sim's node does what a real one does instead:

- **Page placement**: the OS backs the arrays with 2 MiB huge pages on random physical frames of
  the socket's memory (seeded per node), so arrays that the model puts 1 GiB apart land anywhere.
- **Channel hash**: 256-byte granules are spread over the socket's channels by an XOR hash of the
  granule's address bits (``g ^ g>>3 ^ g>>11``), not by plain interleaving.
- **Bank hash**: within a channel, a line's bits are, from the least significant:
  column (3 bits), bank group, column (rest), bank, rank, row; bank group, bank and rank are then
  XORed with low row bits (Haswell-EP-style permutation), a different hash from the model's.
- **Row outcomes**: an open-page controller per channel that serves its queue in windows of
  ``QUEUE_REQUESTS`` arrivals, the requests of a window to the same row together (a batching
  first-ready scheduler, not the model's cycle-level one); a request hits when the previous request
  served by its bank (rank, group, bank) was to the same row; otherwise it activates (and, in the
  steady state, precharges the row that was open).

Only a prefix of each socket's request stream is decoded (``PREFIX_REQUESTS``); every count is per
request and scales to the full run. Pure numpy, a few milliseconds per socket.

Example:
    >>> from hdeem_watch.dram.memspec import preset
    >>> out = socket_row_outcomes(preset("samsung-m393a1g43db0-cpb"), "read", 1 << 20, 4, 4, seed=1)
    >>> out.requests.shape, round(float(out.requests.sum()), 6)
    ((4, 2), 1.0)
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np

from hdeem_watch.dram.kernels import access_pattern, iteration_lines, kernel_iterations, kernel_lines

#: Requests of a socket's stream that are decoded (the rest scales linearly).
PREFIX_REQUESTS = 1 << 15
#: Bytes of the OS pages that back the arrays (transparent huge pages).
PAGE_BYTES = 2 << 20
LINE_BYTES = 64
#: Lines per channel granule (256 B).
GRANULE_LINES = 4
#: Column bits below the bank-group bits (consecutive lines of a channel alternate bank groups).
COLUMN_LOW_BITS = 3
#: Requests of a channel's queue that the controller may serve out of order (same row together).
QUEUE_REQUESTS = 64


@dataclass(frozen=True)
class RowOutcomes:
    """Per channel and rank, the share of a socket's requests and what they cost (per request of the socket).

    Attributes:
        requests: shape (channels, ranks): share of the socket's requests (sums to 1).
        writes: shape (channels, ranks): share that are writes.
        activations: shape (channels, ranks): row activations per socket request.
        hit_rate: row hits / requests over the socket (for reports).
    """

    requests: np.ndarray
    writes: np.ndarray
    activations: np.ndarray
    hit_rate: float


def _bits(n: int) -> int:
    return max(0, int(n) - 1).bit_length()


@functools.lru_cache(maxsize=16)
def _frames(seed: int, n_frames: int, socket: int) -> np.ndarray:
    """The physical frame of each virtual huge page of a socket (a seeded permutation)."""
    return np.random.default_rng([int(seed), 2 ** 20 + socket]).permutation(n_frames).astype(np.uint64)


def socket_stream(kernel: str, elements: int, threads: int, budget: int = PREFIX_REQUESTS,
                  seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Virtual line addresses and write flags of a prefix of one socket's stream (threads round-robin).

    Each thread owns a contiguous chunk of the iterations; per iteration it touches each operand in
    order (a read-for-ownership before a write of a line not also read), one iteration of each thread
    in turn. An iteration's line is itself, a multiple of it (strided kernels) or random over the
    array (random kernels; drawn from the node's ``seed``, not the model's).
    Arrays sit one after another in virtual memory, each rounded up to whole pages.
    """
    pattern = access_pattern(kernel)
    lines = kernel_lines(elements)
    iterations = kernel_iterations(kernel, elements)
    width = len(pattern)
    threads = max(1, int(threads))
    steps = max(1, min(-(-iterations // threads), budget // max(1, threads * width)))
    chunk = -(-iterations // threads)
    step = (np.arange(threads, dtype=np.uint64)[None, :] * np.uint64(chunk)
            + np.arange(steps, dtype=np.uint64)[:, None]).ravel()
    step = step[step < np.uint64(max(1, iterations))]
    line = iteration_lines(kernel, lines, step, seed=seed + 7919)
    page_lines = PAGE_BYTES // LINE_BYTES
    span = -(-max(1, lines) // page_lines) * page_lines
    arrays = {name: i for i, name in enumerate(dict.fromkeys(a for a, _ in pattern))}
    addresses = np.empty((line.size, width), dtype=np.uint64)
    is_write = np.zeros((line.size, width), dtype=bool)
    for column, (array, write) in enumerate(pattern):
        addresses[:, column] = line + np.uint64(arrays[array] * span)
        is_write[:, column] = write
    return addresses.ravel(), is_write.ravel()


def socket_row_outcomes(spec: Any, kernel: str, elements: int, threads: int, channels: int, *, seed: int,
                        socket: int = 0) -> RowOutcomes:
    """Row outcomes of one socket's share of a run: ``elements`` doubles per array, ``threads`` threads.

    Args:
        spec: the memspec of one DIMM (ranks, bank groups, banks, rows, columns, burst length).
        kernel: kernel name (:data:`hdeem_watch.dram.kernels.KERNELS`).
        elements: doubles per array on this socket.
        threads: threads on this socket (>= 1).
        channels: memory channels of the socket (one DIMM each).
        seed: the node's seed (page placement).
        socket: the socket (its own page placement).
    """
    return _outcomes(spec.nbr_of_ranks, spec.nbr_of_bankgroups, spec.nbr_of_banks // max(1, spec.nbr_of_bankgroups),
                     spec.nbr_of_rows, spec.nbr_of_columns // spec.burst_length, str(kernel), int(elements),
                     int(threads), int(channels), int(seed), int(socket))


@functools.lru_cache(maxsize=512)
def _outcomes(ranks: int, groups: int, banks: int, rows: int, bursts_per_row: int, kernel: str, elements: int,
              threads: int, channels: int, seed: int, socket: int) -> RowOutcomes:
    vline, is_write = socket_stream(kernel, elements, threads, seed=seed)
    page_lines = np.uint64(PAGE_BYTES // LINE_BYTES)
    channel_lines = ranks * groups * banks * rows * bursts_per_row
    n_frames = max(1, channels * channel_lines // int(page_lines))
    frames = _frames(seed, n_frames, socket)
    pline = frames[(vline // page_lines) % np.uint64(n_frames)] * page_lines + vline % page_lines
    granule = pline // np.uint64(GRANULE_LINES)
    mixed = granule ^ (granule >> np.uint64(3)) ^ (granule >> np.uint64(11))
    channel = (mixed % np.uint64(channels)).astype(np.int64)
    local = (granule // np.uint64(channels)) * np.uint64(GRANULE_LINES) + pline % np.uint64(GRANULE_LINES)
    low = min(COLUMN_LOW_BITS, _bits(bursts_per_row))
    shift = low
    group = (local >> np.uint64(shift)) % np.uint64(groups)
    shift += _bits(groups) + _bits(bursts_per_row) - low
    bank = (local >> np.uint64(shift)) % np.uint64(banks)
    shift += _bits(banks)
    rank = (local >> np.uint64(shift)) % np.uint64(ranks)
    shift += _bits(ranks)
    row = (local >> np.uint64(shift)) % np.uint64(rows)
    bank ^= row % np.uint64(banks)
    group ^= (row >> np.uint64(_bits(banks))) % np.uint64(groups)
    rank ^= (row >> np.uint64(_bits(banks) + _bits(groups))) % np.uint64(ranks)
    rank_i = rank.astype(np.int64)
    key = ((channel * ranks + rank_i) * groups + group.astype(np.int64)) * banks + bank.astype(np.int64)
    # each channel's queue: requests in windows of QUEUE_REQUESTS, a window's same-row requests served together
    by_channel = np.argsort(channel, kind="stable")
    position = np.empty(channel.size, dtype=np.int64)
    position[by_channel] = np.arange(channel.size) - np.searchsorted(channel[by_channel], channel[by_channel])
    window = position // QUEUE_REQUESTS
    order = np.lexsort((np.arange(key.size), row, window, key))
    k_sorted, row_sorted = key[order], row[order]
    hit_sorted = np.zeros(key.size, dtype=bool)
    hit_sorted[1:] = (k_sorted[1:] == k_sorted[:-1]) & (row_sorted[1:] == row_sorted[:-1])
    hit = np.empty_like(hit_sorted)
    hit[order] = hit_sorted
    n = max(1, key.size)
    cell = channel * ranks + rank_i
    size = channels * ranks
    requests = np.bincount(cell, minlength=size).reshape(channels, ranks) / n
    writes = np.bincount(cell, weights=is_write.astype(float), minlength=size).reshape(channels, ranks) / n
    activations = np.bincount(cell, weights=(~hit).astype(float), minlength=size).reshape(channels, ranks) / n
    return RowOutcomes(requests, writes, activations, float(hit.mean()) if hit.size else 0.0)
