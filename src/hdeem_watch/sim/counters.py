"""The simulated node's IMC counters (``counters = "sim"``), made from its own hidden commands.

:class:`SimCounters` reads the sim's hidden per-DIMM commands
(:meth:`~hdeem_watch.sources.sim.SimSource.hidden_commands`) and shows them with the gaps of a real
Haswell-EP IMC (:func:`~hdeem_watch.sim.imc_events.imc_event_counts`: channel sums, RD and RDA in one
count, explicit precharges only, most refreshes invisible, PPD only when all ranks are in it). Its
channels are ``S<socket>.imc<box>`` with the Haswell-EP box numbers (MC m channel c → box 4m + c)
and each maps to the DRAM power sensor that measures it.

Example:
    >>> from hdeem_watch.sources.sim import SimSource
    >>> t = [0]
    >>> sim = SimSource(seed=1, clock=lambda: t[0], wall_clock=lambda: 0); sim.open()
    >>> counters = SimCounters(sim)
    >>> [c.name for c in counters.channels()][:4]
    ['S0.imc0', 'S0.imc1', 'S0.imc4', 'S0.imc5']
    >>> t[0] = 1_000_000_000
    >>> snap = counters.read()
    >>> snap.t_ns, round(snap.counts["S0.imc0"]["dclk"] * 0.9375e-9, 3)
    (1000000000, 1.0)
"""

from __future__ import annotations

from typing import Protocol

from hdeem_watch.counters.event_tables import TABLES, EventTable
from hdeem_watch.counters.source import CounterChannel, CounterSnapshot
from hdeem_watch.dram.stats import CommandStats
from hdeem_watch.sim.imc_events import imc_event_counts, role_counts_from_events
from hdeem_watch.sim.layout import SimLayout
from hdeem_watch.sim.plan import TruthNode

#: What the sim's IMC hides (shares of the truth it does not show, see ``imc_role_counts``).
SIM_OPPORTUNISTIC_REFRESH = 0.9
SIM_PAGE_CLOSE = 0.25


class HiddenCommandSource(Protocol):
    """A source that knows the DRAM commands behind its samples (the simulated node)."""

    layout: SimLayout
    truth_node: TruthNode

    def hidden_commands(self) -> tuple[int, list[CommandStats]]:
        """``(t_ns on the sample axis, cumulative per-DIMM statistics)``."""
        ...

    def hidden_commands_at(self, t_ns: int) -> list[CommandStats] | None:
        """The cumulative per-DIMM statistics at exactly ``t_ns``, None when not (or no longer) known."""
        ...


def haswell_box(channel: int) -> int:
    """Haswell-EP/Broadwell-EP box of a socket's ``channel``-th channel (MC m channel c → 4m + c)."""
    return 4 * (channel // 2) + channel % 2


def _cas(stats: CommandStats) -> float:
    return sum(stats.total(f) for f in ("rd", "rda", "wr", "wra"))


class SimCounters:
    """The simulated node's memory-controller counters (see the module docstring).

    On a DDR5 node (its memspec a :class:`~hdeem_watch.dram.memspec_ddr5.MemSpecDDR5`, its units
    sub-channels) two consecutive units are one IMC channel, counted as Sapphire Rapids counts it by
    default: the channel's ranks are both sub-channels' ranks, and the CASes of each pseudo-channel
    (``cas_pch0``/``cas_pch1``) are its own sub-channel's. Channel ``S<socket>.imc<n>`` is then the
    socket's n-th channel.

    Args:
        sim: the simulated node (opened).
        generation: the event table to imitate (default Haswell-EP, the HDEEM nodes' CPU; Sapphire
            Rapids on a DDR5 node).
    """

    kind = "sim"

    def __init__(self, sim: HiddenCommandSource, generation: str | None = None) -> None:
        from hdeem_watch.dram.memspec_ddr5 import MemSpecDDR5

        self.sim = sim
        ddr5 = isinstance(sim.truth_node.spec, MemSpecDDR5)
        self.table: EventTable = TABLES[generation or ("sapphire-rapids" if ddr5 else "haswell-ep")]
        self._units = 2 if ddr5 else 1
        layout = sim.layout
        self.ranks = int(sim.truth_node.spec.nbr_of_ranks)
        per_socket: dict[int, int] = {}
        channels = []
        for d in range(0, len(layout.dimm_socket), self._units):
            socket = layout.dimm_socket[d]
            index = per_socket.get(socket, 0)
            per_socket[socket] = index + 1
            box = index if ddr5 else haswell_box(index)
            channels.append(CounterChannel(f"S{socket}.imc{box}", socket, layout.dimm_sensor[d]))
        self._channels = tuple(channels)

    def channels(self) -> tuple[CounterChannel, ...]:
        """One channel per DIMM of the sim (one DIMM per channel; a DDR5 DIMM's two sub-channels are one)."""
        return self._channels

    def read(self) -> CounterSnapshot:
        """The counts an IMC would show for the sim's hidden commands so far."""
        t_ns, stats = self.sim.hidden_commands()
        return self._snapshot(int(t_ns), stats)

    def read_at(self, t_ns: int) -> CounterSnapshot | None:
        """The counts at exactly ``t_ns`` (the samples' time axis) — a window edge — or None when the
        sim does not know that time's commands yet (a run's plan still being computed) or no longer
        (older than a retired run). Interpolating between reads instead would spread a run's commands
        over the whole gap between the read before its plan was known and the one after."""
        stats = self.sim.hidden_commands_at(int(t_ns))
        return None if stats is None else self._snapshot(int(t_ns), stats)

    def _snapshot(self, t_ns: int, stats: list[CommandStats]) -> CounterSnapshot:
        counts = {}
        for n, channel in enumerate(self._channels):
            units = stats[n * self._units:(n + 1) * self._units]
            merged = CommandStats(ranks=tuple(rank for unit in units for rank in unit.ranks))
            pch0 = 0.5
            if self._units == 2 and (cas := _cas(merged)) > 0:
                pch0 = _cas(units[0]) / cas
            events = imc_event_counts(merged, self.table, opportunistic_refresh_share=SIM_OPPORTUNISTIC_REFRESH,
                                      page_close_share=SIM_PAGE_CLOSE, pch0_share=pch0)
            counts[channel.name] = role_counts_from_events(self.table, events)
        return CounterSnapshot(t_ns, counts)

    def close(self) -> None:
        """Nothing to release."""
