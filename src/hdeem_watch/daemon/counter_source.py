"""The daemon's counter source, chosen by ``counters = "perf" | "sim" | "replay" | "none"``.

- ``sim`` (:class:`SimCounters`): the simulated node's IMC counters, made from its own hidden
  commands (:meth:`~hdeem_watch.sources.sim.SimSource.hidden_commands`) with the gaps of a real
  Haswell-EP IMC (:func:`~hdeem_watch.counters.sim_counters.imc_event_counts`: channel sums, RD and
  RDA in one count, explicit precharges only, most refreshes invisible, PPD only when all ranks are
  in it). Its channels are ``S<socket>.imc<box>`` with the Haswell-EP box numbers (MC m channel c →
  box 4m + c) and each maps to the DIMM-pair sensor that measures it.
- ``perf`` (:class:`PerfCounters`): the host plan's events opened through ``perf_event_open``
  (:class:`~hdeem_watch.counters.perf_reader.PerfCounterReader`); each read's per-event deltas are
  scaled for multiplexing and summed per role (:class:`~hdeem_watch.counters.source.RoleTotals`).
- ``replay``: the counters recorded beside a recording, played with it (:mod:`hdeem_watch.daemon.counters.record`).
- ``none``: no counters (runs are modelled from their kernel only).

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

import errno
from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

from hdeem_watch.channels import dimm_pair_channel
from hdeem_watch.counters.event_tables import TABLES, EventTable
from hdeem_watch.counters.sim_counters import imc_event_counts, role_counts_from_events
from hdeem_watch.counters.source import (
    COUNTER_KINDS,
    CounterChannel,
    CounterSnapshot,
    CounterSource,
    RoleTotals,
)
from hdeem_watch.dram.stats import CommandStats
from hdeem_watch.errors import InputError

#: What the sim's IMC hides (shares of the truth it does not show, see ``imc_role_counts``).
SIM_OPPORTUNISTIC_REFRESH = 0.9
SIM_PAGE_CLOSE = 0.25


@runtime_checkable
class HasHiddenCommands(Protocol):
    """A source that knows the DRAM commands behind its samples (the simulated node)."""

    layout: Any

    def hidden_commands(self) -> tuple[int, list[CommandStats]]:
        """``(t_ns on the sample axis, cumulative per-DIMM statistics)``."""
        ...


def haswell_box(channel: int) -> int:
    """Haswell-EP/Broadwell-EP box of a socket's ``channel``-th channel (MC m channel c → 4m + c)."""
    return 4 * (channel // 2) + channel % 2


class SimCounters:
    """The simulated node's memory-controller counters (see the module docstring).

    Args:
        sim: the simulated node (opened).
        generation: the event table to imitate (default Haswell-EP, the HDEEM nodes' CPU).
    """

    kind = "sim"

    def __init__(self, sim: HasHiddenCommands, generation: str = "haswell-ep") -> None:
        self.sim = sim
        self.table: EventTable = TABLES[generation]
        layout = sim.layout
        spec_ranks = getattr(getattr(sim, "truth_node", None), "spec", None)
        self.ranks = int(getattr(spec_ranks, "nbr_of_ranks", 2))
        per_socket: dict[int, int] = {}
        channels = []
        for d, socket in enumerate(layout.dimm_socket):
            index = per_socket.get(socket, 0)
            per_socket[socket] = index + 1
            channels.append(CounterChannel(f"S{socket}.imc{haswell_box(index)}", socket, layout.dimm_sensor[d]))
        self._channels = tuple(channels)

    def channels(self) -> tuple[CounterChannel, ...]:
        """One channel per DIMM of the sim (one DIMM per channel)."""
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
        at = getattr(self.sim, "hidden_commands_at", None)
        stats = at(int(t_ns)) if at is not None else None
        return None if stats is None else self._snapshot(int(t_ns), stats)

    def _snapshot(self, t_ns: int, stats: list[CommandStats]) -> CounterSnapshot:
        counts = {}
        for channel, dimm_stats in zip(self._channels, stats, strict=True):
            events = imc_event_counts(dimm_stats, self.table, opportunistic_refresh_share=SIM_OPPORTUNISTIC_REFRESH,
                                      page_close_share=SIM_PAGE_CLOSE)
            counts[channel.name] = role_counts_from_events(self.table, events)
        return CounterSnapshot(t_ns, counts)

    def close(self) -> None:
        """Nothing to release."""


class PerfCounters:
    """The host's IMC counters through ``perf_event_open``.

    Args:
        plan: the host plan (:func:`~hdeem_watch.counters.host_plan.plan_host`), usable.
        reader: the ``perf_event_open`` port.
        sample_time: monotonic ns → the power samples' time axis.
        clock: monotonic clock (ns).
        ranks: ranks per channel.
        sensors: channel name → DRAM power channel (None: unknown).

    Raises:
        InputError: an event cannot be opened (permissions explained, or the PMU is missing).
    """

    kind = "perf"

    def __init__(self, plan: Any, reader: Any, *, sample_time: Callable[[int], int], clock: Callable[[], int],
                 ranks: int, sensors: dict[str, str | None] | None = None) -> None:
        from hdeem_watch.counters.session import CounterSession

        self.table = plan.table
        self.ranks = int(ranks)
        self._sample_time = sample_time
        self._clock = clock
        self._channels = tuple(CounterChannel(c.name, c.socket, (sensors or {}).get(c.name)) for c in plan.channels)
        self._session = CounterSession(reader, plan.channels, plan.events)
        try:
            self._session.open()
        except OSError as error:
            raise InputError(open_error(error, plan)) from None
        self._previous = self._session.read()
        self._totals = RoleTotals()
        roles = {e.role for e in plan.events}
        self._totals.add({c.name: dict.fromkeys(roles, 0.0) for c in plan.channels})

    def channels(self) -> tuple[CounterChannel, ...]:
        """The plan's channels."""
        return self._channels

    def read(self) -> CounterSnapshot:
        """Read every event; add the scaled deltas since the previous read."""
        now = self._clock()
        current = self._session.read()
        self._totals.add(self._session.role_deltas(self._previous, current))
        self._previous = current
        return self._totals.snapshot(self._sample_time(now))

    def close(self) -> None:
        """Close every event."""
        self._session.close()


def imc_sensors(channels: Any, power_channels: set[str]) -> dict[str, str | None]:
    """IMC channel → the DRAM power channel measuring it: the HDEEM pair (per socket, boxes in
    ascending order are channels A, B, C, … node-wide; ``DDR_AB`` = a socket's first two) when the power
    source has it, else RAPL's ``DRAM<socket>``, else None.

    >>> from hdeem_watch.counters.host_plan import PlannedChannel
    >>> chans = [PlannedChannel(f"S{s}.imc{b}", s, b, f"uncore_imc_{b}", 13, 12 * s) for s in (0, 1) for b in (0, 1, 4, 5)]
    >>> sensors = imc_sensors(chans, {"DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH"})
    >>> sensors["S0.imc4"], sensors["S1.imc1"]
    ('DDR_CD', 'DDR_EF')
    >>> imc_sensors(chans, {"DRAM0", "DRAM1"})["S1.imc5"]
    'DRAM1'
    """
    boxes: dict[int, list[Any]] = {}
    for channel in channels:
        boxes.setdefault(channel.socket, []).append(channel)
    out: dict[str, str | None] = {}
    for socket, members in boxes.items():
        ordered = sorted(members, key=lambda c: c.box)
        for index, channel in enumerate(ordered):
            pair = dimm_pair_channel(socket, index, len(ordered))
            out[channel.name] = pair if pair in power_channels else (
                f"DRAM{socket}" if f"DRAM{socket}" in power_channels else None)
    return out


def open_error(error: OSError, plan: Any) -> str:
    """One line: why ``perf_event_open`` of the plan's events failed, and the fix."""
    if error.errno in (errno.EACCES, errno.EPERM):
        return f"counters perf: not allowed to open uncore events ({error.strerror}): {plan.access.explanation}"
    if error.errno in (errno.ENOENT, errno.ENODEV, errno.EINVAL, errno.EOPNOTSUPP):
        return (f"counters perf: the kernel refused an IMC event ({error.strerror}): the uncore_imc PMU or "
                "the event does not exist on this host (hdeem-watch counters shows what it found)")
    return f"counters perf: perf_event_open failed: {error.strerror or error}"


def make_counter_source(kind: str, source: object, *, sample_time: Callable[[int], int], clock: Callable[[], int],
                        ranks: int = 2, sysfs_root: str | None = None,
                        replay_file: str | None = None) -> CounterSource | None:
    """The configured counter source (None for ``"none"``).

    Raises:
        InputError: one line: the kind cannot work with this power source or host, and why.
    """
    if kind == "none":
        return None
    if kind == "sim":
        if not isinstance(source, HasHiddenCommands):
            raise InputError(f"counters = 'sim' needs source = 'sim' (the {getattr(source, 'kind', '?')} source "
                             "has no simulated memory controller); use counters = 'perf' on a real node")
        return SimCounters(source)
    if kind == "perf":
        from hdeem_watch.counters.host_plan import plan_host
        from hdeem_watch.counters.perf_reader import PerfCounterReader
        from hdeem_watch.counters.pmu_discovery import DEFAULT_SYSFS_ROOT

        plan = plan_host(sysfs_root or DEFAULT_SYSFS_ROOT, ranks=ranks)
        if not plan.usable:
            raise InputError("counters perf: " + "; ".join(plan.reasons))
        names = {info.name for info in source.channels()} if hasattr(source, "channels") else set()
        return PerfCounters(plan, PerfCounterReader(), sample_time=sample_time, clock=clock, ranks=ranks,
                            sensors=imc_sensors(plan.channels, names))
    if kind == "replay":
        from hdeem_watch.daemon.counters.record import CounterReplay

        if not replay_file:
            raise InputError("counters = 'replay' needs source = 'replay' and its recording (replay_file)")
        return CounterReplay(replay_file, source)
    raise InputError(f"counters = {kind!r}; expected one of {', '.join(COUNTER_KINDS)}")
