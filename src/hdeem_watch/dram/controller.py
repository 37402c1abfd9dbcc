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
from dataclasses import dataclass, replace
from dataclasses import fields as fields_of
from typing import Any

import numpy as np

from hdeem_watch.dram.mapping import AddressMapping, Geometry
from hdeem_watch.dram.pipeline import prepared
from hdeem_watch.dram.scheduler import SchedulerConfig, serve
from hdeem_watch.dram.stats import CommandStats, RankStats
from hdeem_watch.errors import InputError

POLICIES = ("open", "closed")
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


@dataclass(frozen=True)
class Timing:
    """The DDR4 timings the model uses, in clock cycles (from ``MemSpec.timings``)."""

    ras: int
    rcd: int
    rp: int
    rl: int
    wl: int
    al: int
    rtp: int
    wr: int
    ccd_s: int
    ccd_l: int
    wtr_s: int
    wtr_l: int
    rtrs: int
    rfc: int
    refi: int
    burst: int

    @classmethod
    def from_spec(cls, spec: Any) -> Timing:
        """Read the timings of a memspec.

        Raises:
            InputError: naming a missing timing.
        """
        t = spec.timings
        def get(key: str, default: int | None = None) -> int:
            if key in t:
                return int(t[key])
            if default is None:
                raise InputError(f"memspec: memtimingspec.{key} missing; the controller model needs it")
            return default
        rfc = int(spec.trfc) if hasattr(spec, "trfc") else get("RFC1")
        return cls(ras=get("RAS"), rcd=get("RCD"), rp=get("RP"), rl=get("RL"), wl=get("WL"), al=get("AL", 0),
                   rtp=get("RTP"), wr=get("WR"), ccd_s=get("CCD_S"), ccd_l=get("CCD_L"),
                   wtr_s=get("WTR_S"), wtr_l=get("WTR_L"), rtrs=get("RTRS", 1), rfc=rfc, refi=get("REFI"),
                   burst=max(1, int(spec.burst_length) // int(spec.data_rate)))


@dataclass(frozen=True)
class Commands:
    """The command set the model issued (all arrays of one length per kind, cycles as int64).

    Attributes:
        act_cycle, act_rank, act_bank, act_row: activations (``act_bank`` flat in the rank).
        pre_cycle, pre_rank, pre_bank: explicit single-bank precharges.
        col_cycle, col_rank, col_bank, col_row, col_column, col_write, col_auto: column commands
            (``col_auto``: with auto-precharge, RDA/WRA).
        ref_cycle: refresh times (PREA of every rank at ``ref_cycle``, REFA ``refa_delay`` later).
        end_cycle: the evaluation time T.
        refa_delay: cycles from a refresh's PREA to its REFA (tRP).
        start_cycle: where the window starts (0 unless this is a later chunk).
    """

    act_cycle: np.ndarray
    act_rank: np.ndarray
    act_bank: np.ndarray
    act_row: np.ndarray
    pre_cycle: np.ndarray
    pre_rank: np.ndarray
    pre_bank: np.ndarray
    col_cycle: np.ndarray
    col_rank: np.ndarray
    col_bank: np.ndarray
    col_row: np.ndarray
    col_column: np.ndarray
    col_write: np.ndarray
    col_auto: np.ndarray
    ref_cycle: np.ndarray
    end_cycle: int
    refa_delay: int = 0
    start_cycle: int = 0


@dataclass(frozen=True)
class ControllerResult:
    """What :func:`simulate` returns.

    Attributes:
        stats: per-rank statistics of the channel (the energy model's input).
        requests, reads, writes: requests served.
        row_hits, row_misses, row_conflicts: outcome of each request at its first command.
        cycles: total DRAM cycles (the END of the emitted trace).
        commands: the issued command set (for :func:`hdeem_watch.dram.command_emit.write_drampower_trace`),
            ``None`` unless :func:`simulate` was asked to keep it.
        geometry: the organisation simulated.
    """

    stats: CommandStats
    requests: int
    reads: int
    writes: int
    row_hits: int
    row_misses: int
    row_conflicts: int
    cycles: int
    commands: Commands | None
    geometry: Geometry


def simulate(
    spec: Any,
    addresses: np.ndarray,
    is_write: np.ndarray,
    *,
    policy: str = "open",
    mapping: str = "RoBaRaCoCh",
    xor_bank: bool = False,
    channel: int = 0,
    scheduler: SchedulerConfig | None = None,
    keep_commands: bool = False,
) -> ControllerResult:
    """Serve a request stream on one channel and count the commands.

    Args:
        spec: memspec of the channel (:class:`hdeem_watch.dram.memspec.MemSpec`).
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
                             scheduler=scheduler, keep_commands=keep_commands)


def simulate_requests(
    spec: Any,
    n: int,
    requests: Callable[[int, int], tuple[np.ndarray, np.ndarray]],
    *,
    policy: str = "open",
    mapping: str = "RoBaRaCoCh",
    xor_bank: bool = False,
    channel: int = 0,
    scheduler: SchedulerConfig | None = None,
    keep_commands: bool = False,
) -> ControllerResult:
    """:func:`simulate` of ``n`` requests that ``requests(lo, hi)`` gives (addresses, write flags)
    chunk by chunk, in the preparing stage (e.g. parsed from a trace file while the chunk before
    is timed: :func:`hdeem_watch.dram.trace_simulation.simulate_trace`)."""
    if policy not in POLICIES:
        raise InputError(f"policy {policy!r}: expected one of {', '.join(POLICIES)}")
    geometry = Geometry.from_spec(spec)
    timing = Timing.from_spec(spec)
    config = scheduler or SchedulerConfig()
    address_mapping = AddressMapping(geometry, mapping, xor_bank=xor_bank)
    from hdeem_watch.dram.row_outcomes import Outcomes, row_outcomes
    from hdeem_watch.dram.timing_model import run_timing

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
    # chunk i + 1 is prepared (decoded, in service order) in a worker process or thread while
    # chunk i is timed; only the timing depends on the chunk before
    mode = ("inline" if not PIPELINE else
            "process" if PIPELINE_PROCESS and not keep_commands and pieces >= PROCESS_MIN_CHUNKS else "thread")
    slot_bytes = 72 * (bounds[1] - bounds[0] + 1) + 4096
    for i, (gbank, row, column, writes, outcomes) in enumerate(prepared(prepare, pieces, mode, slot_bytes)):
        part = run_timing(geometry, timing, config, policy, gbank=gbank, row=row, column=column, write=writes,
                          start=start, close_at_end=i < pieces - 1, outcomes=outcomes, keep_commands=keep_commands)
        start = part.cycles
        if not keep_commands:
            part = replace(part, commands=None)
        parts.append(part)
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
        geometry=parts[0].geometry,
    )


def stats_from_commands(geometry: Geometry, timing: Timing, commands: Commands,
                        run_rank: np.ndarray, run_open: np.ndarray, run_close: np.ndarray,
                        closed_by_prea: np.ndarray, auto_pre_rank: np.ndarray) -> CommandStats:
    """Per-rank statistics of a command set, given the bank-open intervals it implies.

    Args:
        geometry, timing: the channel.
        commands: the command set.
        run_rank: rank of each bank-open interval.
        run_open, run_close: the interval (ACT cycle, precharge cycle or END).
        closed_by_prea: intervals closed by a refresh's PREA.
        auto_pre_rank: rank of each implicit precharge of an RDA/WRA that closed its bank.
    """
    ranks = []
    end = commands.end_cycle
    window = end - commands.start_cycle
    refreshes = commands.ref_cycle.size
    per_rank = geometry.ranks
    # column commands per (rank, write, auto) in one pass
    columns = _column_counts(commands.col_rank, commands.col_write, commands.col_auto, per_rank)
    acts = np.bincount(commands.act_rank, minlength=per_rank)
    explicit = np.bincount(commands.pre_rank, minlength=per_rank)
    autos = np.bincount(auto_pre_rank, minlength=per_rank)
    prea = np.bincount(run_rank[closed_by_prea], minlength=per_rank)
    ref_start = commands.ref_cycle + timing.rp
    ref_stop = np.minimum(ref_start + timing.rfc, end)
    for r in range(per_rank):
        mine = run_rank == r
        opened, closed = run_open[mine], run_close[mine]
        union = _union_length(np.concatenate((opened, ref_start)), np.concatenate((closed, ref_stop)))
        ranks.append(RankStats(
            act=float(acts[r]), pre=float(explicit[r] + prea[r] + autos[r]),
            rd=float(columns[r, 0, 0]), wr=float(columns[r, 1, 0]),
            rda=float(columns[r, 0, 1]), wra=float(columns[r, 1, 1]),
            ref=float(refreshes), cycles_total=float(window), cycles_act=float(union),
            cycles_pre=float(window - union),
            bank_active_cycles=float(np.sum(closed - opened) + geometry.banks * np.sum(ref_stop - ref_start)),
        ))
    return CommandStats(ranks=tuple(ranks))


def _column_counts(rank: np.ndarray, write: np.ndarray, auto: np.ndarray, ranks: int) -> np.ndarray:
    """Column commands per (rank, write, auto-precharge): an array ``[rank, write, auto]``."""
    if ranks > 8:  # many ranks: one bincount
        code = rank.astype(np.int64) * 4 + write.view(np.uint8) * 2 + auto.view(np.uint8)
        return np.bincount(code, minlength=4 * ranks).reshape(-1, 2, 2)
    counts = np.zeros((ranks, 2, 2), dtype=np.int64)
    any_auto = bool(auto.any())
    write_auto = write & auto if any_auto else None
    for r in range(ranks):
        mine = rank == r if ranks > 1 else np.ones(rank.size, dtype=bool)
        total = np.count_nonzero(mine)
        writes = np.count_nonzero(write & mine)
        autos = np.count_nonzero(auto & mine) if any_auto else 0
        both = np.count_nonzero(write_auto & mine) if write_auto is not None else 0
        counts[r] = ((total - writes - autos + both, autos - both), (writes - both, both))
    return counts


def _union_length(starts: np.ndarray, stops: np.ndarray) -> int:
    """Total length of the union of half-open intervals ``[start, stop)``."""
    valid = stops > starts
    starts, stops = starts[valid], stops[valid]
    if starts.size == 0:
        return 0
    order = np.argsort(starts, kind="stable")
    starts, stops = starts[order], stops[order]
    reach = np.maximum.accumulate(stops)
    # a new merged block starts where an interval begins after everything before it ended
    new_block = np.empty(starts.size, dtype=bool)
    new_block[0] = True
    new_block[1:] = starts[1:] > reach[:-1]
    first = np.flatnonzero(new_block)
    # a block ends where the next begins; its stop is the running maximum there
    block_stop = reach[np.append(first[1:] - 1, starts.size - 1)]
    return int(np.sum(block_stop - starts[first]))
