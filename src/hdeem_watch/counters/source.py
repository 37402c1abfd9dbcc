"""The counter-source port: cumulative per-channel role counts on the power samples' time axis.

A counter source (perf on a real host, the simulated node's own counters, a replayed recording)
answers :meth:`CounterSource.read` with a :class:`CounterSnapshot`: per memory channel and role
(:data:`~hdeem_watch.counters.event_tables.ROLES`), the count since the source opened, already
corrected for multiplexing and wrap, at a time ``t_ns`` on the power source's sample axis. A window
is the difference of two snapshots (:func:`window_counts`); a snapshot between two reads is their
linear interpolation (:func:`interpolate`), which is exact for the idle stretch before a run starts.

A poll whose event never ran (multiplexing) adds nothing to the total and one to the role's
``unknown`` tally: a window that spans such a poll is NaN for that role (unknown is not zero).

Example:
    >>> a = CounterSnapshot(0, {"S0.imc0": {"act": 10.0}})
    >>> b = CounterSnapshot(100, {"S0.imc0": {"act": 30.0}})
    >>> window_counts(a, b)
    {'S0.imc0': {'act': 20.0}}
    >>> interpolate([a, b], 25).counts["S0.imc0"]["act"]
    15.0
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol

from hdeem_watch.counters.event_tables import EventTable

#: ``counters`` settings of the daemon: where a window's DRAM commands come from (``auto``: the
#: power source's own counters when they can be opened, see :func:`auto_counter_kind`).
COUNTER_KINDS = ("auto", "none", "sim", "perf", "replay")
#: channel → role → count.
Counts = dict[str, dict[str, float]]


@dataclass(frozen=True)
class CounterChannel:
    """One memory channel a counter source counts.

    Attributes:
        name: ``S<socket>.imc<box>``.
        socket: its socket.
        sensor: the DRAM power channel that measures its DIMMs (e.g. ``DDR_AB``), None if unknown.
    """

    name: str
    socket: int
    sensor: str | None = None


@dataclass(frozen=True)
class CounterSnapshot:
    """Cumulative counts of every channel and role at ``t_ns`` (the power samples' time axis).

    Attributes:
        t_ns: when (ns on the sample-time axis: HDEEM's wall clock, the sim's own time).
        counts: channel → role → count since the source opened (NaN: never counted).
        unknown: channel → role → polls in which the role could not be counted (absent = 0).
    """

    t_ns: int
    counts: Mapping[str, Mapping[str, float]]
    unknown: Mapping[str, Mapping[str, int]] = field(default_factory=dict)


class CounterSource(Protocol):
    """Memory-controller counters of a node, read on demand.

    Attributes:
        kind: ``"perf"``, ``"sim"`` or ``"replay"``.
        table: the CPU generation's event table (what the counts mean, their gaps).
        ranks: ranks per channel (for the per-rank split).
    """

    kind: str
    table: EventTable
    ranks: int

    def channels(self) -> tuple[CounterChannel, ...]:
        """The channels counted."""
        ...

    def read(self) -> CounterSnapshot:
        """The counts now (raises ``OSError``/``RuntimeError`` when the counters cannot be read)."""
        ...

    def close(self) -> None:
        """Release the counters."""
        ...


def auto_counter_kind(source_kind: str, *, replay_has_counters: bool) -> str:
    """The counter kind ``counters = "auto"`` tries for a power source of ``source_kind``.

    The simulated node counts with its own memory controllers, a replay plays back the counters
    recorded beside it (none if there were none), and a real node (HDEEM, RAPL) tries its IMC PMUs
    through perf; whether perf may open them is known only when it tries.

    Example:
        >>> auto_counter_kind("hdeem", replay_has_counters=False)
        'perf'
        >>> auto_counter_kind("replay", replay_has_counters=False)
        'none'
    """
    if source_kind == "sim":
        return "sim"
    if source_kind == "replay":
        return "replay" if replay_has_counters else "none"
    return "perf"


def window_counts(start: CounterSnapshot, end: CounterSnapshot) -> Counts:
    """Channel → role → count between two snapshots (NaN where unknown in between or missing)."""
    out: Counts = {}
    for channel, roles in end.counts.items():
        before = start.counts.get(channel, {})
        gaps_end, gaps_start = end.unknown.get(channel, {}), start.unknown.get(channel, {})
        out[channel] = {}
        for role, value in roles.items():
            if gaps_end.get(role, 0) != gaps_start.get(role, 0):
                out[channel][role] = math.nan
            else:
                out[channel][role] = float(value) - float(before.get(role, math.nan))
    return out


def interpolate(history: Sequence[CounterSnapshot], t_ns: int) -> CounterSnapshot:
    """The snapshot at ``t_ns`` from a time-ordered history (linear between the two around it;
    the first or last one outside it).

    Raises:
        ValueError: an empty history.
    """
    if not history:
        raise ValueError("no counter snapshot yet")
    i = bisect.bisect_left(history, t_ns, key=lambda s: s.t_ns)
    if i < len(history) and history[i].t_ns == t_ns:
        return history[i]
    if i == 0:
        return history[0]
    if i == len(history):
        return history[-1]
    a, b = history[i - 1], history[i]
    w = (t_ns - a.t_ns) / (b.t_ns - a.t_ns)
    counts = {ch: {role: float(v) + (float(b.counts[ch].get(role, math.nan)) - float(v)) * w
                   for role, v in roles.items()} for ch, roles in a.counts.items() if ch in b.counts}
    return CounterSnapshot(int(t_ns), counts, b.unknown)


class RoleTotals:
    """Per-poll role deltas (already scaled for multiplexing) summed into cumulative totals.

    Example:
        >>> totals = RoleTotals()
        >>> totals.add({"S0.imc0": {"act": 5.0, "refresh": float("nan")}})
        >>> totals.snapshot(7).counts, totals.snapshot(7).unknown
        ({'S0.imc0': {'act': 5.0, 'refresh': 0.0}}, {'S0.imc0': {'refresh': 1}})
    """

    def __init__(self) -> None:
        self._counts: Counts = {}
        self._unknown: dict[str, dict[str, int]] = {}

    def add(self, deltas: Mapping[str, Mapping[str, float]]) -> None:
        """Add one poll's deltas; a NaN delta counts as a poll in which the role was unknown."""
        for channel, roles in deltas.items():
            counts = self._counts.setdefault(channel, {})
            for role, delta in roles.items():
                counts.setdefault(role, 0.0)
                if math.isfinite(delta):
                    counts[role] += float(delta)
                else:
                    gaps = self._unknown.setdefault(channel, {})
                    gaps[role] = gaps.get(role, 0) + 1

    def snapshot(self, t_ns: int) -> CounterSnapshot:
        """The totals now, at ``t_ns``."""
        return CounterSnapshot(int(t_ns), {c: dict(r) for c, r in self._counts.items()},
                               {c: dict(r) for c, r in self._unknown.items()})
