"""The controller model's vocabulary: its timings, the command set it issues, what it returns,
and the per-rank statistics of a command set.

:func:`hdeem_watch.dram.controller.simulate` drives the model; :mod:`hdeem_watch.dram.timing_model`
computes a chunk's commands (:class:`Commands`) and turns them into statistics with
:func:`stats_from_commands`. Both use these types, so they live here, below both.

Example:
    >>> from hdeem_watch.dram.memspec import preset
    >>> Timing.from_spec(preset("ddr4-2133-x8-4gb")).rcd
    15
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hdeem_watch.dram.act_spacing import RecentActs
from hdeem_watch.dram.mapping import Geometry
from hdeem_watch.dram.memspec import MemSpec
from hdeem_watch.dram.stats import CommandStats, RankStats
from hdeem_watch.errors import InputError


@dataclass(frozen=True)
class Timing:
    """The timings the model uses, in clock cycles (from ``MemSpec.timings``; DDR5 through
    :func:`hdeem_watch.dram.ddr5_channel.subchannel_spec`)."""

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
    #: write-to-write spacing in one bank group (DDR5's tCCD_L_WR; DDR4: tCCD_L)
    ccd_l_wr: int = 0
    #: ACT to ACT of one rank, different bank groups (0: no rule)
    rrd_s: int = 0
    #: ACT to ACT of one bank group (0: no rule)
    rrd_l: int = 0
    #: four-activation window of a rank (0: no rule)
    faw: int = 0

    @property
    def ccd_l_write(self) -> int:
        """Spacing of two writes to one bank group: ``ccd_l_wr`` where given, else tCCD_L."""
        return self.ccd_l_wr or self.ccd_l

    @classmethod
    def from_spec(cls, spec: MemSpec) -> Timing:
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
        rfc = int(spec.trfc)
        return cls(ras=get("RAS"), rcd=get("RCD"), rp=get("RP"), rl=get("RL"), wl=get("WL"), al=get("AL", 0),
                   rtp=get("RTP"), wr=get("WR"), ccd_s=get("CCD_S"), ccd_l=get("CCD_L"),
                   wtr_s=get("WTR_S"), wtr_l=get("WTR_L"), rtrs=get("RTRS", 1), rfc=rfc, refi=get("REFI"),
                   burst=max(1, int(spec.burst_length) // int(spec.data_rate)), ccd_l_wr=get("CCD_L_WR", 0),
                   rrd_s=get("RRD_S", 0), rrd_l=get("RRD_L", 0), faw=get("FAW", 0))


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
        recent_acts: the last activations (:class:`~hdeem_watch.dram.act_spacing.RecentActs`).
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
    #: the last activations, which tRRD and tFAW still see from the next chunk
    recent_acts: RecentActs | None = None


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
