"""A vectorised DDR4 memory-controller model: request stream → per-rank command statistics.

The Ramulator step of the seed pipeline, as array operations (no Python loop per request). The
model, in the order it is computed (details and the comparison with Ramulator in
``docs/dram-stats.md``):

1. **Mapping**: every request is split into rank, bank group, bank, row, column
   (:mod:`hdeem_watch.dram.mapping`).
2. **Service order** (:mod:`hdeem_watch.dram.scheduler`): reads and writes sit in separate queues;
   writes are drained in batches between the high and low watermarks while the read queue stays
   full; within a read phase or a write batch, requests to the same open row are served together
   (FR-FCFS), at most ``hit_cap`` in a row before the oldest other request gets its turn.
3. **Row-buffer outcome** per bank in service order: hit, miss (bank precharged) or conflict
   (another row open); a closed-page policy precharges a bank when no queued request hits it.
4. **Timing**: column commands in service order are spaced by the DDR4 column-to-column rules
   (tCCD_S/L, read↔write turnaround, tWTR_S/L, rank switch) and by the bank rules of each miss or
   conflict (PRE after tRAS/tRTP/write recovery, tRP, ACT, tRCD; ACT no earlier than the request
   enters the queue). Both are max-plus recurrences solved with cumulative maxima.
5. **Refresh**: every tREFI each rank is closed (PREA) and refreshed; traffic stalls for
   tRP + tRFC + tRCD. The stall windows are inserted in closed form; rows a refresh closes cost an
   extra activation (including rows that were activated ahead of their first column command).
6. **Statistics** from the resulting command set: ACT, PRE (explicit, PREA-closed banks, auto),
   RD/WR (RDA/WRA under the closed policy), REF; per rank the cycles with a bank open (refresh
   included) and with all banks precharged, and the sum of bank-open cycles. The same command set
   can be written as a DRAMPower trace (:mod:`hdeem_watch.dram.command_emit`), so both give the
   same energy.

Example:
    >>> from hdeem_watch.dram.memspec import preset
    >>> from hdeem_watch.dram.kernels import kernel_requests
    >>> addresses, is_write = kernel_requests("read", 8 * 4096)
    >>> result = simulate(preset("ddr4-2133-x8-4gb"), addresses, is_write)
    >>> result.reads, result.writes, result.row_hits + result.row_misses + result.row_conflicts
    (4096, 0, 4096)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import fields as fields_of
from dataclasses import replace

import numpy as np

from hdeem_watch.dram.command_set import Commands, ControllerResult, Timing
from hdeem_watch.dram.mapping import AddressMapping, Geometry
from hdeem_watch.dram.memspec import MemSpec
from hdeem_watch.dram.pipeline import prepared
from hdeem_watch.dram.progress import ProgressCallback
from hdeem_watch.dram.row_outcomes import Outcomes, row_outcomes
from hdeem_watch.dram.scheduler import SchedulerConfig, serve
from hdeem_watch.dram.stats import CommandStats, RankStats
from hdeem_watch.dram.timing_model import run_timing
from hdeem_watch.errors import InputError

POLICIES = ("open", "closed")
#: The phase :func:`simulate` reports progress under.
PROGRESS_PHASE = "controller model"
#: Requests served per chunk by :func:`simulate`.
CHUNK_REQUESTS = 1 << 17
#: Prepare the next chunk (decode, service order, row outcomes) while one is timed.
PIPELINE = True
#: ... in a forked worker process where that is safe and the commands are not kept
#: (:mod:`hdeem_watch.dram.pipeline`), else in a thread.
PIPELINE_PROCESS = True
#: Fewest chunks worth a worker process (forking costs a few ms).
PROCESS_MIN_CHUNKS = 4
#: Compute the row outcomes while preparing (else while timing): balances the two stages.
OUTCOMES_AHEAD = False


def simulate(
    spec: MemSpec,
    addresses: np.ndarray,
    is_write: np.ndarray,
    *,
    policy: str = "open",
    mapping: str = "RoBaRaCoCh",
    xor_bank: bool = False,
    channel: int = 0,
    scheduler: SchedulerConfig | None = None,
    keep_commands: bool = False,
    progress: ProgressCallback | None = None,
) -> ControllerResult:
    """Serve a request stream on one channel and count the commands.

    Args:
        spec: memspec of the channel.
        addresses: physical byte addresses (``uint64``), in arrival order.
        is_write: write flags, same length.
        policy: ``"open"`` (rows stay open until a conflict or refresh) or ``"closed"`` (a row is
            precharged, by RDA/WRA, when no queued request hits it).
        mapping: address-mapping scheme (:mod:`hdeem_watch.dram.mapping`).
        xor_bank: XOR bank hashing.
        channel: which channel to simulate when the memspec has several (others' requests are
            ignored).
        scheduler: queue sizes, watermarks and hit cap (defaults: Ramulator's).
        keep_commands: keep the issued commands in ``result.commands`` (for
            :func:`hdeem_watch.dram.command_emit.write_drampower_trace`); off by default to save memory.
        progress: called as ``progress("controller model", requests_done, requests_total)``
            after each chunk (:mod:`hdeem_watch.dram.progress`).

    Long streams are served in chunks of about :data:`CHUNK_REQUESTS` requests (bounded memory,
    cache-friendly); each chunk but the last ends by precharging the banks left open (one PRE per
    open bank per chunk: a negligible deviation).

    Raises:
        InputError: for a bad policy, mapping, memspec or mismatched arrays.
    """
    addresses = np.asarray(addresses, dtype=np.uint64)
    is_write = np.asarray(is_write, dtype=bool)
    if addresses.shape != is_write.shape or addresses.ndim != 1:
        raise InputError(f"requests: {addresses.size} addresses but {is_write.size} write flags")
    return simulate_requests(spec, addresses.size, lambda lo, hi: (addresses[lo:hi], is_write[lo:hi]),
                             policy=policy, mapping=mapping, xor_bank=xor_bank, channel=channel,
                             scheduler=scheduler, keep_commands=keep_commands, progress=progress)


def simulate_requests(
    spec: MemSpec,
    n: int,
    requests: Callable[[int, int], tuple[np.ndarray, np.ndarray]],
    *,
    policy: str = "open",
    mapping: str = "RoBaRaCoCh",
    xor_bank: bool = False,
    channel: int = 0,
    scheduler: SchedulerConfig | None = None,
    keep_commands: bool = False,
    progress: ProgressCallback | None = None,
) -> ControllerResult:
    """:func:`simulate` of ``n`` requests that ``requests(lo, hi)`` gives (addresses, write flags)
    chunk by chunk, in the preparing stage (e.g. parsed from a trace file while the chunk before
    is timed: :func:`hdeem_watch.dram.trace_simulation.simulate_trace`)."""
    if policy not in POLICIES:
        raise InputError(f"policy {policy!r}: expected one of {', '.join(POLICIES)}")
    geometry = Geometry.from_spec(spec)
    config = scheduler or SchedulerConfig()
    timing = Timing.from_spec(spec)
    if not config.activation_rules:  # no tRRD/tFAW rule binds (the timing plan's lifts and the spacing)
        timing = replace(timing, rrd_s=0, rrd_l=0, faw=0)
    address_mapping = AddressMapping(geometry, mapping, xor_bank=xor_bank)
    pieces = max(1, n // CHUNK_REQUESTS)
    bounds = [n * i // pieces for i in range(pieces + 1)]

    row_bits = geometry.rows.bit_length() - 1
    key_type = np.int32 if (geometry.ranks * geometry.banks) << row_bits <= 1 << 31 else np.int64

    def prepare(i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray, Outcomes | None]:
        """Chunk ``i`` decoded and in service order (independent of the chunks before it); with its
        row-buffer outcomes if :data:`OUTCOMES_AHEAD`."""
        chunk, writes = requests(bounds[i], bounds[i + 1])
        lanes, gbank, row, column = address_mapping.decode_packed(chunk, column=keep_commands)
        if lanes is not None:
            keep = lanes == channel
            if not keep.all():
                gbank, row, writes = gbank[keep], row[keep], writes[keep]
                column = column[keep] if column is not None else None
        key: np.ndarray = np.left_shift(gbank.astype(key_type, copy=False), row_bits)
        key |= row
        key, writes, order = serve(key, row_bits, writes, config, want_order=column is not None)
        row = key & ((1 << row_bits) - 1)
        key >>= row_bits
        outcomes = row_outcomes(geometry, config, policy, gbank=key, row=row) if OUTCOMES_AHEAD else None
        return key, row, column[order] if column is not None and order is not None else None, writes, outcomes

    parts: list[ControllerResult] = []
    start = 0
    recent = None
    # chunk i + 1 is prepared (decoded, in service order) in a worker process or thread while
    # chunk i is timed; only the timing depends on the chunk before
    mode = ("inline" if not PIPELINE else
            "process" if PIPELINE_PROCESS and not keep_commands and pieces >= PROCESS_MIN_CHUNKS else "thread")
    slot_bytes = 72 * (bounds[1] - bounds[0] + 1) + 4096
    for i, (gbank, row, column, writes, outcomes) in enumerate(prepared(prepare, pieces, mode, slot_bytes)):
        part = run_timing(geometry, timing, config, policy, gbank=gbank, row=row, column=column, write=writes,
                          start=start, close_at_end=i < pieces - 1, outcomes=outcomes, keep_commands=keep_commands,
                          prior=recent)
        start, recent = part.cycles, part.recent_acts
        if not keep_commands:
            part = replace(part, commands=None)
        parts.append(part)
        if progress is not None:
            progress(PROGRESS_PHASE, bounds[i + 1], n)
    return parts[0] if len(parts) == 1 else _merge(parts)


def _merge(parts: list[ControllerResult]) -> ControllerResult:
    """One result from consecutive chunks (counts and residency add up; windows are contiguous)."""
    ranks = []
    for r in range(len(parts[0].stats.ranks)):
        totals = {f.name: sum(getattr(p.stats.ranks[r], f.name) for p in parts) for f in fields_of(RankStats)}
        ranks.append(RankStats(**totals))
    commands = None
    if all(p.commands is not None for p in parts):
        chunks = [p.commands for p in parts if p.commands is not None]
        arrays = {f.name: np.concatenate([getattr(c, f.name) for c in chunks])
                  for f in fields_of(Commands) if f.name not in ("end_cycle", "refa_delay", "start_cycle")}
        commands = Commands(**arrays, end_cycle=chunks[-1].end_cycle, refa_delay=chunks[-1].refa_delay,
                            start_cycle=chunks[0].start_cycle)
    return ControllerResult(
        stats=CommandStats(ranks=tuple(ranks)), requests=sum(p.requests for p in parts),
        reads=sum(p.reads for p in parts), writes=sum(p.writes for p in parts),
        row_hits=sum(p.row_hits for p in parts), row_misses=sum(p.row_misses for p in parts),
        row_conflicts=sum(p.row_conflicts for p in parts), cycles=parts[-1].cycles, commands=commands,
        geometry=parts[0].geometry, recent_acts=parts[-1].recent_acts,
    )
