"""The per-rank DDR5 state machine of DRAMPower v6.2 (``standards/ddr5/DDR5Core``): trace -> CommandStats.

:func:`trace_stats_ddr5` walks a command trace in order, with DRAMPower's queue of implicit commands
(events scheduled for a later cycle, run in time order, same-cycle ones in the order they were
created, before the first command whose cycle is not earlier; those after the evaluation time T
never happen). Rules:

- ACT opens the bank (restarting its active interval); PRE closes an open bank and counts a
  precharge (a PRE to a precharged bank is nothing). PREA is PRE to every bank of the rank; PRESB
  with bank b is PRE to bank ``b mod banksPerGroup`` of every bank group.
- RDA/WRA count as reads/writes and schedule a PRE of their bank at
  ``max(bank's active-interval start + RAS, t + offset)`` with offset ``RTP`` (reads) or
  ``BL/dataRate + WL + WR`` (writes).
- REFA makes every bank active (an interval is started only where none is open) until t + tRFC
  (``RFC1_slr``, or ``RFC2_slr`` in refresh mode 2), then precharges them without counting a
  precharge; the rank counts as active until t + tRFC. REFSB with bank b does this for bank
  ``b mod banksPerGroup`` of every bank group for ``RFCsb_slr`` cycles.
- SREFEN is a REFA, then self-refresh from t + tRFC; SREFEX closes the self-refresh interval at t
  (DRAMPower v6.2's CLI aborts on SREFEX for DDR5; its core does this).
- PDEA/PDEP/PDXA/PDXP take effect at ``max(t, earliest)``, earliest being, over the banks of the
  rank, the latest of: active-interval start + RCD (banks ever activated), last counted precharge +
  RP (banks ever precharged), refresh end. Active power-down closes the rank's and banks' active
  intervals; its exit reopens those of banks whose interval it closed (banks activated at least
  once) and, if any, the rank's. Precharge power-down only counts its own residency.

At T: a rank's ``cycles_act`` is its active-interval time, ``cycles_pdna``/``cycles_pdnp``/
``cycles_sref`` the power-down and self-refresh residencies, ``cycles_pre`` = T minus those;
``bank_active_cycles`` sums the banks' active-interval times (refreshes included).

This is a per-command loop (plain Python objects), written for exactness against DRAMPower rather
than speed; a 1-million-command trace takes seconds (docs/dram-model.md, "DDR5").

Example:
    >>> import pathlib, tempfile
    >>> from hdeem_watch.dram.command_trace import read_command_trace
    >>> from hdeem_watch.dram.memspec_ddr5 import load_memspec_ddr5
    >>> spec = load_memspec_ddr5(pathlib.Path(__file__).parents[3] / "examples" / "ddr5_drampower_test.json")
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "t.csv"
    >>> _ = path.write_text("0,ACT,0,0,3,0,0\\n15,RDA,0,0,3,0,0\\n40,REFSB,0,0,1,0,0\\n100,END,0,0,0,0,0\\n")
    >>> rank = trace_stats_ddr5(spec, read_command_trace(path)).ranks[0]
    >>> rank.act, rank.pre, rank.rda, rank.refsb, rank.cycles_act, rank.bank_active_cycles
    (1.0, 1.0, 1.0, 1.0, 40.0, 60.0)
"""

from __future__ import annotations

import heapq
from collections.abc import Callable
from dataclasses import dataclass, field

from hdeem_watch.dram.command_trace import COMMANDS, CommandTrace
from hdeem_watch.dram.memspec_ddr5 import MemSpecDDR5
from hdeem_watch.dram.stats import CommandStats, RankStats
from hdeem_watch.errors import InputError


@dataclass
class _Interval:
    """DRAMPower's ``interval_counter``: accumulated cycles plus one optional open interval."""

    count: int = 0
    start: int | None = None
    end: int | None = None

    def is_open(self) -> bool:
        return self.start is not None and self.end is None

    def open_at(self, t: int) -> None:
        self.start, self.end = t, None

    def close_at(self, t: int) -> None:
        if self.start is not None and self.end is None:
            self.end = t
            self.count += t - self.start

    def count_at(self, t: int) -> int:
        if self.start is not None and self.end is None and t > self.start:
            return self.count + t - self.start
        return self.count


@dataclass
class _Bank:
    active: bool = False
    act: _Interval = field(default_factory=_Interval)
    n_act: int = 0
    n_pre: int = 0
    latest_pre: int = 0
    refresh_end: int = 0


@dataclass
class _Rank:
    banks: list[_Bank]
    act: _Interval = field(default_factory=_Interval)
    pdna: _Interval = field(default_factory=_Interval)
    pdnp: _Interval = field(default_factory=_Interval)
    sref: _Interval = field(default_factory=_Interval)
    end_refresh: int = 0

    def is_active(self, t: int) -> bool:
        return t < self.end_refresh or any(bank.active for bank in self.banks)


class _Core:
    """The state of every rank, the implicit-command queue, and the command handlers."""

    def __init__(self, spec: MemSpecDDR5) -> None:
        self.spec = spec
        tm = spec.timings
        self.ras, self.rcd, self.rp = tm["RAS"], tm["RCD"], tm["RP"]
        self.offset_rd = tm["RTP"]
        self.offset_wr = spec.burst_length // spec.data_rate + tm["WL"] + tm["WR"]
        self.ranks = [_Rank(banks=[_Bank() for _ in range(spec.nbr_of_banks)]) for _ in range(spec.nbr_of_ranks)]
        self.queue: list[tuple[int, int, Callable[[], None]]] = []
        self.created = 0

    def later(self, t: int, action: Callable[[], None]) -> None:
        """Schedule an implicit command (same-cycle ones run in creation order)."""
        heapq.heappush(self.queue, (t, self.created, action))
        self.created += 1

    def run_until(self, t: int) -> None:
        """Run every implicit command scheduled at or before cycle ``t``."""
        while self.queue and self.queue[0][0] <= t:
            heapq.heappop(self.queue)[2]()

    def same_banks(self, bank: int) -> list[int]:
        """Bank ``bank mod banksPerGroup`` of every bank group (PRESB, REFSB)."""
        per_group = self.spec.banks_per_group
        return [group * per_group + bank % per_group for group in range(self.spec.nbr_of_bankgroups)]

    def activate(self, rank: _Rank, bank: _Bank, t: int) -> None:
        bank.n_act += 1
        bank.act.open_at(t)
        if not rank.is_active(t):
            rank.act.open_at(t)
        bank.active = True

    def precharge(self, rank: _Rank, bank: _Bank, t: int) -> None:
        if not bank.active:
            return
        bank.n_pre += 1
        bank.act.close_at(t)
        bank.latest_pre = t
        bank.active = False
        if not rank.is_active(t):
            rank.act.close_at(t)

    def auto_precharge(self, rank: _Rank, bank: _Bank, t: int, offset: int) -> None:
        when = max((bank.act.start or 0) + self.ras, t + offset)
        self.later(when, lambda: self.precharge(rank, bank, when))

    def refresh_bank(self, rank: _Rank, bank: _Bank, t: int, duration: int) -> None:
        if not rank.is_active(t):
            rank.act.open_at(t)
        bank.active = True
        end = t + duration
        bank.refresh_end = end
        if not bank.act.is_open():
            bank.act.open_at(t)

        def done() -> None:
            bank.active = False
            bank.act.close_at(end)
            if not rank.is_active(end):
                rank.act.close_at(end)

        self.later(end, done)

    def refresh_all(self, rank: _Rank, t: int) -> None:
        for bank in rank.banks:
            self.refresh_bank(rank, bank, t, self.spec.trfc)
        rank.end_refresh = t + self.spec.trfc

    def earliest_power_down(self, rank: _Rank) -> int:
        earliest = 0
        for bank in rank.banks:
            earliest = max(earliest, (bank.act.start or 0) + self.rcd if bank.n_act else 0,
                           bank.latest_pre + self.rp if bank.n_pre else 0, bank.refresh_end)
        return earliest

    def enter_active_power_down(self, rank: _Rank, t: int) -> None:
        rank.pdna.open_at(t)
        rank.act.close_at(t)
        for bank in rank.banks:
            bank.act.close_at(t)

    def exit_active_power_down(self, rank: _Rank, t: int) -> None:
        rank.pdna.close_at(t)
        resumed = False
        for bank in rank.banks:
            if bank.n_act and (bank.act.end or 0) == (rank.pdna.start or 0):
                resumed = True
                bank.act.open_at(t)
        if resumed:
            rank.act.open_at(t)


def _power_state(core: _Core, rank: _Rank, name: str, t: int) -> None:
    """PDEA/PDXA/PDEP/PDXP (delayed to the earliest possible cycle), SREFEN and SREFEX."""
    if name == "SREFEN":
        core.refresh_all(rank, t)
        start = t + core.spec.trfc
        core.later(start, lambda: rank.sref.open_at(start))
        return
    if name == "SREFEX":
        rank.sref.close_at(t)
        return
    when = max(t, core.earliest_power_down(rank))
    action: Callable[[], None] = {
        "PDEA": lambda: core.enter_active_power_down(rank, when),
        "PDXA": lambda: core.exit_active_power_down(rank, when),
        "PDEP": lambda: rank.pdnp.open_at(when),
        "PDXP": lambda: rank.pdnp.close_at(when),
    }[name]
    core.later(when, action)


_ENTRY = {"PDXA": "PDEA", "PDXP": "PDEP", "SREFEX": "SREFEN"}


def _check_power_order(trace: CommandTrace, i: int, name: str, modes: list[str | None], rank: int,
                       sref_start: list[int]) -> None:
    """Entries only when not in power-down/self-refresh, exits only after their entry (as DDR4)."""
    line = f"{trace.path}: line {i + 1}: {name}"
    mode = modes[rank]
    if name in ("PDEA", "PDEP", "SREFEN"):
        if mode is not None:
            raise InputError(f"{line} while the rank is in {mode}; expected its exit first")
        modes[rank] = name
        return
    if mode != _ENTRY[name]:
        raise InputError(f"{line} without a preceding {_ENTRY[name]}"
                         + (f" (the rank is in {mode})" if mode else "") + "; expected matching entry/exit")
    if name == "SREFEX" and int(trace.cycle[i]) < sref_start[rank]:
        raise InputError(f"{line} at cycle {int(trace.cycle[i])} before the self-refresh starts (SREFEN + tRFC "
                         f"= {sref_start[rank]}); expected SREFEX at or after it")
    modes[rank] = None


def _check_ranges(spec: MemSpecDDR5, trace: CommandTrace) -> None:
    for name, values, limit in (("rank", trace.rank, spec.nbr_of_ranks), ("bank", trace.bank, spec.nbr_of_banks)):
        over = values >= limit
        if over.any():
            i = int(over.argmax())
            raise InputError(f"{trace.path}: line {i + 1}: {name} {values[i]} out of range; memspec "
                             f"{spec.memory_id!r} has {limit} ({name} 0..{limit - 1})")


def _rank_stats(core: _Core, rank: _Rank, counts: dict[str, int], end: int) -> RankStats:
    act = rank.act.count_at(end)
    pdna, pdnp, sref = rank.pdna.count_at(end), rank.pdnp.count_at(end), rank.sref.count_at(end)
    return RankStats(
        act=float(sum(b.n_act for b in rank.banks)), pre=float(sum(b.n_pre for b in rank.banks)),
        rd=float(counts["RD"]), wr=float(counts["WR"]), rda=float(counts["RDA"]), wra=float(counts["WRA"]),
        ref=float(counts["REFA"] + counts["SREFEN"]), refsb=float(counts["REFSB"]), cycles_total=float(end),
        cycles_act=float(act), cycles_pre=float(end - act - pdna - pdnp - sref), cycles_pdna=float(pdna),
        cycles_pdnp=float(pdnp), cycles_sref=float(sref),
        bank_active_cycles=float(sum(b.act.count_at(end) for b in rank.banks)))


def trace_stats_ddr5(spec: MemSpecDDR5, trace: CommandTrace) -> CommandStats:
    """Per-rank counts and residency of a DDR5 command trace (the rules are in the module docstring).

    Raises:
        InputError: a rank or bank out of range, or power-down/self-refresh commands out of order
            (with the line number).
    """
    _check_ranges(spec, trace)
    core = _Core(spec)
    counts = [dict.fromkeys(COMMANDS, 0) for _ in range(spec.nbr_of_ranks)]
    modes: list[str | None] = [None] * spec.nbr_of_ranks
    sref_start = [0] * spec.nbr_of_ranks
    for i, (t, code, r, b) in enumerate(zip(trace.cycle.tolist(), trace.cmd.tolist(), trace.rank.tolist(),
                                            trace.bank.tolist())):
        name = COMMANDS[code]
        if name in ("END", "NOP"):
            continue
        core.run_until(t)
        counts[r][name] += 1
        rank = core.ranks[r]
        bank = rank.banks[b]
        if name == "ACT":
            core.activate(rank, bank, t)
        elif name == "PRE":
            core.precharge(rank, bank, t)
        elif name == "PREA":
            for each in rank.banks:
                core.precharge(rank, each, t)
        elif name == "PRESB":
            for k in core.same_banks(b):
                core.precharge(rank, rank.banks[k], t)
        elif name in ("RDA", "WRA"):
            core.auto_precharge(rank, bank, t, core.offset_rd if name == "RDA" else core.offset_wr)
        elif name == "REFA":
            core.refresh_all(rank, t)
        elif name == "REFSB":
            for k in core.same_banks(b):
                core.refresh_bank(rank, rank.banks[k], t, spec.trfcsb)
        elif name in ("PDEA", "PDXA", "PDEP", "PDXP", "SREFEN", "SREFEX"):
            _check_power_order(trace, i, name, modes, r, sref_start)
            if name == "SREFEN":
                sref_start[r] = t + spec.trfc
            _power_state(core, rank, name, t)
    end = trace.end_cycle
    core.run_until(end)
    ranks = tuple(_rank_stats(core, core.ranks[r], counts[r], end) for r in range(spec.nbr_of_ranks))
    return CommandStats(ranks=ranks)

