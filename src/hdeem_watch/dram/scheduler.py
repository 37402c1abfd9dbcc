"""Service order of a request stream: write-drain batches and FR-FCFS row grouping, vectorised.

The controller keeps reads and writes in separate queues (Ramulator: 32 entries each). Writes
wait until the write queue holds more than ``high × size`` entries, then are drained until fewer
than ``low × size`` remain; meanwhile the read queue is full, so the reads that arrived in the
last ``read_queue`` places before the drain started are served after it. The drain batches and
read phases are computed in closed form from the arrival positions.

Within a read phase (cut into windows of at most ``window`` reads) and within a write batch,
FR-FCFS serves the requests to an open row before older requests to other rows of that bank:
within each bank, requests are grouped by row in order of first appearance (the row left open by
the previous segment first), each group in arrival order, at most ``hit_cap + 1`` per turn
(Ramulator 1 caps hits at 16; ``None`` = uncapped, as Ramulator 2). Different banks keep the
places their requests had in arrival order, so bank groups and ranks stay interleaved.

Example:
    >>> import numpy as np
    >>> bank = np.zeros(6, dtype=np.int64); row = np.array([1, 2, 1, 2, 1, 2])
    >>> service_order(bank, row, np.zeros(6, dtype=bool)).tolist()
    [0, 2, 4, 1, 3, 5]
    >>> service_order(np.array([0, 1, 0, 1]), np.array([1, 1, 2, 1]), np.zeros(4, dtype=bool)).tolist()
    [0, 1, 2, 3]
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hdeem_watch.errors import InputError

#: Above this share of requests in multi-row segments, :func:`service_order` regroups every segment.
REGROUP_ALL_SHARE = 0.6


@dataclass(frozen=True)
class SchedulerConfig:
    """Queue and scheduling parameters (defaults: Ramulator's controller).

    Attributes:
        read_queue: read-queue entries.
        write_queue: write-queue entries.
        high: write-drain high watermark (fraction of ``write_queue``).
        low: write-drain low watermark.
        hit_cap: most row hits served in a row before the oldest request; ``None`` = no cap.
        window: longest stretch of reads regrouped at once (the reordering horizon).
        activation_rules: space the activations by tRRD_S/L and tFAW (:mod:`~hdeem_watch.dram.act_spacing`).
            Off by default: on activation-dense streams it makes the model about 10× slower (random
            lines, triad at 24 threads: docs/dram-stats.md "Activation rules"), too slow for the sim
            and the daemon's per-run model, while it moves a DDR4 kernel's cycles by < 0.1 %.
    """

    read_queue: int = 32
    write_queue: int = 32
    high: float = 0.8
    low: float = 0.2
    hit_cap: int | None = 16
    window: int = 64
    hidden_turnaround: int = 3
    hidden_bank: int = 13
    activation_rules: bool = False

    def __post_init__(self) -> None:
        if self.read_queue < 1 or self.write_queue < 2 or self.window < 1:
            raise InputError("scheduler: queue sizes and window must be positive")
        if not 0.0 <= self.low < self.high <= 1.0:
            raise InputError(f"scheduler: watermarks low={self.low}, high={self.high}; expected 0 <= low < high <= 1")
        if self.hit_cap is not None and self.hit_cap < 1:
            raise InputError(f"scheduler: hit_cap {self.hit_cap}; expected >= 1 or None")

    @property
    def drain_batch(self) -> int:
        """Writes served per drain (from above ``high`` to below ``low``; at most the writes queued
        when it starts, so a queue whose ``low`` mark rounds to no entry drains whole)."""
        return min(self.drain_trigger, self.drain_trigger - (int(self.low * self.write_queue) - 1))

    @property
    def drain_trigger(self) -> int:
        """Write-queue occupancy that starts a drain."""
        return int(self.high * self.write_queue) + 1


def served_segments(is_write: np.ndarray, config: SchedulerConfig) -> tuple[np.ndarray, np.ndarray]:
    """The served sequence before row grouping, and where its segments start (closed form).

    The served sequence is read phase 0, write batch 0, read phase 1, ..., the last read phase,
    the remaining writes (each run in arrival order); read phases are cut into windows of
    ``window`` reads. Built from the run lengths, without per-request segment ids.

    Returns:
        ``(served, boundary)``: request indices in served order, and a flag at each segment start.
    """
    served, boundary, _ = _served_runs(is_write, config)
    return served, boundary


def _served_runs(is_write: np.ndarray, config: SchedulerConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`served_segments`, plus the write flags in served order (from the run lengths)."""
    n = is_write.size
    write_pos = np.flatnonzero(is_write)
    n_writes = write_pos.size
    n_reads = n - n_writes
    batch = config.drain_batch
    trigger = config.drain_trigger
    full = max(0, (n_writes - trigger) // batch + 1) if n_writes >= trigger else 0
    trigger_write = trigger - 1 + batch * np.arange(full, dtype=np.int64)
    cut = np.maximum(write_pos[trigger_write] - trigger_write - config.read_queue, 0)
    cut = np.maximum.accumulate(cut) if cut.size else cut
    read_first = np.concatenate(([0], cut))  # first read ordinal of each read phase
    read_len = np.diff(np.append(read_first, n_reads))
    # runs: read phase k, write batch k (k < full); the last read phase, the remaining writes
    lengths = np.empty(2 * (full + 1), dtype=np.int64)
    lengths[0::2] = read_len
    lengths[1::2] = batch
    lengths[-1] = n_writes - full * batch
    run_start = np.cumsum(lengths) - lengths  # served position of each run
    base = np.empty(2 * (full + 1), dtype=np.int64)  # index into (reads, writes) of each run's first
    base[0::2] = read_first
    base[1::2] = n_reads + batch * np.arange(full + 1, dtype=np.int64)
    source = np.repeat(base - run_start, lengths)
    source += np.arange(n, dtype=np.int64)
    both = np.empty(n, dtype=np.int64)
    both[n_reads:] = write_pos
    both[:n_reads] = np.flatnonzero(~is_write)
    served = both[source]
    boundary = np.zeros(n, dtype=bool)
    boundary[run_start[1::2][lengths[1::2] > 0]] = True  # write batches, remaining writes
    windows = -(-read_len // config.window)  # read windows per phase
    total = int(windows.sum())
    first_window = np.cumsum(windows) - windows
    starts = np.repeat(run_start[0::2] - config.window * first_window, windows)
    starts += config.window * np.arange(total, dtype=np.int64)
    boundary[starts] = True
    kinds = np.zeros(lengths.size, dtype=bool)
    kinds[1::2] = True
    return served, boundary, np.repeat(kinds, lengths)


def service_order(bank: np.ndarray, row: np.ndarray, is_write: np.ndarray,
                  config: SchedulerConfig | None = None) -> np.ndarray:
    """Indices of the requests in the order the controller serves them.

    Args:
        bank: global bank index of each request (rank × banks + bank), arrival order.
        row: row of each request.
        is_write: write flags.
        config: scheduler parameters.
    """
    if is_write.size == 0:
        return np.zeros(0, dtype=np.int64)
    row = np.asarray(row, dtype=np.int64)
    row_bits = max(1, int(row.max()).bit_length())
    key = (np.asarray(bank, dtype=np.int64) << row_bits) | row
    order = serve(key, row_bits, np.asarray(is_write, dtype=bool), config, want_order=True)[2]
    assert order is not None
    return order


def serve(key: np.ndarray, bank_shift: int, is_write: np.ndarray, config: SchedulerConfig | None = None, *,
          want_order: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The requests in service order, as their row keys (the work of :func:`service_order`).

    Args:
        key: row key of each request in arrival order, ``bank << bank_shift | row`` (non-negative;
            any numbering of banks and rows that keeps them apart gives the same order).
        bank_shift: bits of the row part of ``key``.
        is_write: write flags.
        config: scheduler parameters.
        want_order: also return the service order (request indices).

    Returns:
        ``(keys, writes, order)``: the row keys and write flags in service order, and the order
        (``None`` unless asked for).
    """
    config = config or SchedulerConfig()
    n = is_write.size
    served, boundary, writes = _served_runs(is_write, config)
    key_s = key[served]
    if n < 2:
        return key_s, writes, served if want_order else None
    # a segment whose requests all go to one row is served as it is
    change = key_s[1:] != key_s[:-1]
    change &= ~boundary[1:]
    n_changes = int(np.count_nonzero(change))
    if n_changes == 0:
        return key_s, writes, served if want_order else None
    seg_start = np.flatnonzero(boundary)
    if n_changes >= REGROUP_ALL_SHARE * (n - seg_start.size):
        # regrouping a one-row segment leaves it as it is: with many mixed segments, regroup all
        out = _regroup(key_s, bank_shift, boundary, seg_start, config.hit_cap, want_order)
        return out[0], writes, served[out[1]] if out[1] is not None else None
    changes = np.cumsum(change, dtype=np.int32)  # row changes inside segments, up to each request
    seg_last = np.append(seg_start[1:], n) - 1
    mixed = changes[np.maximum(seg_last - 1, 0)] > np.where(seg_start > 0, changes[np.maximum(seg_start - 1, 0)], 0)
    mixed &= seg_last > seg_start
    seg_id = np.cumsum(boundary, dtype=np.int32)
    seg_id -= 1
    sub = np.flatnonzero(mixed[seg_id])
    # the row each mixed segment's predecessor left open: kept as the first request before it
    sub_boundary = boundary[sub]
    sub_boundary[0] = True
    sub_start = np.flatnonzero(sub_boundary)
    open_key = np.where(sub[sub_start] > 0, key_s[np.maximum(sub[sub_start] - 1, 0)], -1)
    keys, permutation = _regroup(key_s[sub], bank_shift, sub_boundary, sub_start, config.hit_cap, True,
                                 open_key=open_key)
    assert permutation is not None
    key_s = key_s.copy()
    key_s[sub] = keys
    order = None
    if want_order:
        order = served.copy()
        order[sub] = served[sub][permutation]
    return key_s, writes, order


def _regroup(key: np.ndarray, bank_shift: int, boundary: np.ndarray, seg_start: np.ndarray,
             hit_cap: int | None, want_order: bool, open_key: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray | None]:
    """FR-FCFS order within whole segments: the keys in that order (and the permutation).

    One stable sort by (segment, row key) cuts every group into turns of at most
    ``hit_cap + 1`` requests (blocks, each in arrival order); only the blocks are then ordered by
    (segment, bank, turn, first appearance of their row), and expanded back. ``open_key``: the
    row key each segment starts with open (default: the key before the segment's first request;
    -1 for none).
    """
    m = key.size
    key_bits = max(1, int(key.max()).bit_length())
    sid = np.cumsum(boundary, dtype=np.int64)  # segment of each request, + 1
    wide = sid << key_bits
    wide |= key
    by_group = np.argsort(wide, kind="stable")
    del wide
    # the sort keeps every segment in its place: segment starts stay group starts
    sorted_key = key[by_group]
    new = boundary.copy()
    new[1:] |= sorted_key[1:] != sorted_key[:-1]
    group_start = np.flatnonzero(new)
    if hit_cap is None:
        block_start: np.ndarray = group_start
        block_turn = np.zeros(group_start.size, dtype=np.int64)
    else:
        # each group is cut into turns of hit_cap + 1 requests: the blocks, from the group lengths
        group_len = np.diff(np.append(group_start, m))
        turns = -(-group_len // (hit_cap + 1))
        if int(turns.max()) == 1:
            block_start = group_start
            block_turn = np.zeros(group_start.size, dtype=np.int64)
        else:
            block_group = np.repeat(np.arange(group_start.size), turns)
            block_turn = np.arange(block_group.size, dtype=np.int64) - (np.cumsum(turns) - turns)[block_group]
            block_start = group_start[block_group] + block_turn * (hit_cap + 1)
    block_first = by_group[block_start - block_turn * (hit_cap + 1) if hit_cap is not None else block_start]
    block_sid = sid[block_start] - 1
    block_row_key = sorted_key[block_start].astype(np.int64)
    # rows in order of first appearance, the row left open by the previous segment first (a hit)
    local_first = block_first - seg_start[block_sid]
    if open_key is None:
        open_key = np.full(seg_start.size, -1, dtype=np.int64)
        open_key[1:] = key[seg_start[1:] - 1]
    local_first[block_row_key == open_key[block_sid]] = -1
    seg_len = int(np.diff(np.append(seg_start, m)).max())
    block_bank = block_row_key >> bank_shift
    banks = int(block_bank.max()) + 1
    block_key = ((block_sid * banks + block_bank) * (seg_len + 1) + block_turn) * (seg_len + 2) + local_first + 1
    order = np.argsort(block_key, kind="stable")
    lengths = np.diff(np.append(block_start, m))[order]
    starts = block_start[order]
    # a block is one row: the keys in grouped order need no gather
    grouped_key = np.repeat(block_row_key[order].astype(key.dtype), lengths)
    grouped = None
    if want_order:
        offsets = np.cumsum(lengths) - lengths
        source = np.repeat(starts - offsets, lengths)
        source += np.arange(m, dtype=np.int64)
        grouped = by_group[source]
    # Each bank keeps the places its requests had (banks interleave as they arrived, e.g. across
    # bank groups); within a bank the places are refilled in row-grouped order.
    bank = key >> bank_shift
    bank_change = bank[1:] != bank[:-1]
    bank_change &= ~boundary[1:]
    if not bank_change.any():  # every segment goes to one bank
        return grouped_key, grouped
    bank_bits = max(1, banks.bit_length())
    sid <<= bank_bits
    sid |= bank
    slots = np.argsort(sid, kind="stable")
    out_key = np.empty(m, dtype=key.dtype)
    out_key[slots] = grouped_key
    permutation = None
    if grouped is not None:
        permutation = np.empty(m, dtype=np.int64)
        permutation[slots] = grouped
    return out_key, permutation
