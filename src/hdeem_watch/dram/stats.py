"""Command statistics: the interface between command producers and the energy model.

Everything that turns traffic into DRAM commands (a DRAMPower command trace, the controller model
driven by a request stream, the model of a STREAM-like kernel, a simulated node) produces
:class:`CommandStats`; the energy model (:mod:`hdeem_watch.dram.energy`) turns them into joules
and into the linear columns the calibrator fits. Counts are floats so that statistics can be
scaled (several identical DIMMs, a measured window longer than the modelled one).

Example:
    >>> rank = RankStats(act=10, pre=10, rd=640, cycles_total=10_000, cycles_act=2_000,
    ...                  cycles_pre=8_000, bank_active_cycles=2_000)
    >>> stats = CommandStats(ranks=(rank, RankStats(cycles_total=10_000, cycles_pre=10_000)))
    >>> stats.total("rd")
    640.0
    >>> stats.scaled(2.0).total("act")
    20.0
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields, replace
from typing import TYPE_CHECKING, Any

from hdeem_watch.errors import InputError

if TYPE_CHECKING:
    from hdeem_watch.dram.memspec import MemSpec
    from hdeem_watch.dram.memspec_ddr5 import MemSpecDDR5

#: Command counters of a rank, in the order of the ``counts`` object of ``model energy --json``.
COUNT_FIELDS = ("act", "pre", "rd", "wr", "rda", "wra", "ref")
#: :data:`COUNT_FIELDS` of a DDR5 rank (same-bank refreshes added).
DDR5_COUNT_FIELDS = (*COUNT_FIELDS, "refsb")
#: State-residency fields of a rank, as ``cycles_<name>``, in the order of ``cycles`` in the JSON.
CYCLE_FIELDS = ("act", "pre", "pdna", "pdnp", "sref")
#: Fields that :func:`stretch_stats` scales with the window (state residency, bank activity).
_STRETCHED = ("cycles_act", "cycles_pre", "cycles_pdna", "cycles_pdnp", "cycles_sref", "bank_active_cycles")


@dataclass(frozen=True)
class RankStats:
    """Command counts and state residency of one rank over an evaluation window of ``cycles_total``.

    Attributes:
        act: activations.
        pre: precharges that closed an open bank, explicit (PRE, each bank closed by PREA) and
            implicit (the auto-precharge of RDA/WRA, the precharge after a refresh is not counted).
        rd: reads without auto-precharge (BL bursts).
        wr: writes without auto-precharge.
        rda: reads with auto-precharge.
        wra: writes with auto-precharge.
        ref: all-bank refreshes (REFA, and the refresh that starts a self-refresh).
        refsb: DDR5 same-bank refreshes (REFSB commands; each refreshes one bank in every bank
            group). Always 0 for DDR4.
        cycles_total: the window T in clock cycles.
        cycles_act: cycles with at least one bank active (including refresh).
        cycles_pre: cycles with all banks precharged and not in power-down or self-refresh.
        cycles_pdna: active power-down cycles.
        cycles_pdnp: precharge power-down cycles.
        cycles_sref: self-refresh cycles.
        bank_active_cycles: sum over the banks of each bank's active cycles (used only by the
            bank-wise ρ ≠ 1 form of the background energy).
    """

    act: float = 0.0
    pre: float = 0.0
    rd: float = 0.0
    wr: float = 0.0
    rda: float = 0.0
    wra: float = 0.0
    ref: float = 0.0
    refsb: float = 0.0
    cycles_total: float = 0.0
    cycles_act: float = 0.0
    cycles_pre: float = 0.0
    cycles_pdna: float = 0.0
    cycles_pdnp: float = 0.0
    cycles_sref: float = 0.0
    bank_active_cycles: float = 0.0

    def scaled(self, factor: float) -> RankStats:
        """Every count and cycle figure multiplied by ``factor``."""
        return RankStats(**{f.name: getattr(self, f.name) * factor for f in fields(self)})

    def to_dict(self) -> dict[str, float]:
        """Plain dict of every field (JSON-ready)."""
        return {k: float(v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str = "stats") -> RankStats:
        """Build from a dict of this class's field names; unknown keys or non-numbers are errors.

        Raises:
            InputError: naming ``where`` and the bad key or value.
        """
        known = {f.name for f in fields(cls)}
        values: dict[str, float] = {}
        for key, value in data.items():
            if key not in known:
                raise InputError(f"{where}: unknown field {key!r}; expected one of {sorted(known)}")
            if isinstance(value, bool) or not isinstance(value, int | float) or value != value or value < 0:
                raise InputError(f"{where}.{key}: {value!r} is not a non-negative number")
            values[key] = float(value)
        return cls(**values)


@dataclass(frozen=True)
class CommandStats:
    """Per-rank statistics of one channel (one memspec) over one window.

    Attributes:
        ranks: one :class:`RankStats` per rank, index = rank number.
    """

    ranks: tuple[RankStats, ...]

    def total(self, name: str) -> float:
        """Sum of field ``name`` (e.g. ``"act"`` or ``"cycles_act"``) over the ranks."""
        return float(sum(getattr(rank, name) for rank in self.ranks))

    def scaled(self, factor: float) -> CommandStats:
        """Every rank scaled by ``factor`` (e.g. identical channels, or a longer window)."""
        return CommandStats(ranks=tuple(rank.scaled(factor) for rank in self.ranks))

    def with_rank(self, index: int, rank: RankStats) -> CommandStats:
        """A copy with rank ``index`` replaced."""
        ranks = list(self.ranks)
        ranks[index] = rank
        return replace(self, ranks=tuple(ranks))

    def to_dict(self) -> dict[str, Any]:
        """``{"ranks": [ {field: value, ...}, ... ]}`` (JSON-ready; read back by :meth:`from_dict`)."""
        return {"ranks": [rank.to_dict() for rank in self.ranks]}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str = "stats") -> CommandStats:
        """Read the form written by :meth:`to_dict`.

        Raises:
            InputError: naming ``where`` and what was wrong.
        """
        ranks = data.get("ranks") if isinstance(data, Mapping) else None
        if not isinstance(ranks, list) or not ranks:
            raise InputError(f"{where}: expected an object with a non-empty list 'ranks'")
        parsed = []
        for i, rank in enumerate(ranks):
            if not isinstance(rank, Mapping):
                raise InputError(f"{where}.ranks[{i}]: expected an object")
            parsed.append(RankStats.from_dict(rank, where=f"{where}.ranks[{i}]"))
        return cls(ranks=tuple(parsed))


def refresh_interval(spec: MemSpec | MemSpecDDR5) -> float:
    """tREFI in cycles: DDR4's ``REFI``; DDR5's ``REFI1``, or ``REFI2`` in refresh mode 2 (0: none given)."""
    timings = spec.timings
    if "REFI" in timings:
        return float(timings["REFI"] or 0)
    return float(timings.get("REFI2" if spec.ref_mode == 2 else "REFI1", 0) or 0)


def stretch_stats(spec: MemSpec | MemSpecDDR5, stats: CommandStats, window_s: float, *, name: str = "run") -> CommandStats:
    """``stats`` with its state residency and refreshes stretched to a window of ``window_s``.

    The command counts stay (the run issued them once); the fraction of time in each state is kept
    and applied to the longer (or shorter) window, and refresh is scaled with the window because
    the device refreshes whatever the kernel does. A rank with an empty window (``cycles_total ==
    0``) becomes precharged standby for the whole window with a refresh every tREFI
    (:func:`refresh_interval`: ``REFI``, or DDR5's ``REFI1``/``REFI2`` by refresh mode).

    Args:
        spec: the memspec, DDR4 or DDR5 (``tck_s``, :func:`refresh_interval`).
        stats: the model's statistics (any window length).
        window_s: the measured window in seconds, > 0.
        name: the run's name, for messages.

    Raises:
        InputError: a window that is not a positive number, or commands in an empty window.

    Example:
        >>> from hdeem_watch.dram.memspec import preset
        >>> spec = preset("ddr4-2133-x8-4gb")
        >>> idle = CommandStats(ranks=(RankStats(), RankStats()))
        >>> stretched = stretch_stats(spec, idle, 1.0)
        >>> round(stretched.ranks[0].cycles_total * spec.tck_s, 9), stretched.total("ref") > 0
        (1.0, True)
    """
    if isinstance(window_s, bool) or not isinstance(window_s, int | float) or not math.isfinite(window_s) \
            or window_s <= 0:
        raise InputError(f"run {name!r}: window_s = {window_s!r}; expected a duration > 0 s")
    cycles_w = float(window_s) / float(spec.tck_s)
    refi = refresh_interval(spec)
    ranks = []
    for i, rank in enumerate(stats.ranks):
        if rank.cycles_total <= 0:
            if any(getattr(rank, f) > 0 for f in DDR5_COUNT_FIELDS):
                raise InputError(f"run {name!r}: rank {i} has commands but cycles_total = 0")
            ranks.append(RankStats(cycles_total=cycles_w, cycles_pre=cycles_w,
                                   ref=cycles_w / refi if refi > 0 else 0.0))
            continue
        factor = cycles_w / rank.cycles_total
        changes: dict[str, float] = {f: getattr(rank, f) * factor for f in _STRETCHED}
        changes["ref"] = rank.ref * factor
        changes["refsb"] = rank.refsb * factor
        changes["cycles_total"] = cycles_w
        ranks.append(replace(rank, **changes))
    return CommandStats(ranks=tuple(ranks))
