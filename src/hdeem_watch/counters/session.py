"""Open a host plan's events through a :class:`~hdeem_watch.counters.reader.CounterReader` and read them.

The thin shell between the plan (what to count) and the pure arithmetic (window deltas, roles,
``CommandStats``): :meth:`CounterSession.open` opens every planned event on every planned channel
(one ``perf_event_open`` each, CPU-wide on the channel's socket CPU), :meth:`CounterSession.read`
returns one :class:`~hdeem_watch.counters.arithmetic.Reading` per channel and event, and
:meth:`CounterSession.role_deltas` turns two such snapshots into per-channel role counts.

If any open fails, the events opened so far are closed and the ``OSError`` propagates (its errno
tells permission from absence; :mod:`hdeem_watch.counters.permissions` explains the former).

Example:
    >>> from hdeem_watch.counters.reader import FakeCounterReader
    >>> plan_events = ()  # a plan with no events opens nothing
    >>> CounterSession(FakeCounterReader(lambda *a: 0), channels=(), events=plan_events).open().read()
    {}
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from hdeem_watch.counters.arithmetic import PERF_COUNT_BITS, Reading, role_total, window_deltas
from hdeem_watch.counters.host_plan import PlannedChannel, PlannedEvent
from hdeem_watch.counters.reader import CounterReader

#: channel name → event name → reading.
Snapshot = dict[str, dict[str, Reading]]


class CounterSession:
    """The open events of one host plan.

    Args:
        reader: the ``perf_event_open`` port (real or fake).
        channels: the plan's channels.
        events: the plan's events (the same on every channel).
    """

    def __init__(self, reader: CounterReader, channels: Sequence[PlannedChannel],
                 events: Sequence[PlannedEvent]) -> None:
        self._reader = reader
        self._channels = tuple(channels)
        self._events = tuple({e.name: e for e in events}.values())
        self._roles: dict[str, list[str]] = {}
        for event in events:
            self._roles.setdefault(event.role, []).append(event.name)
        self._handles: dict[tuple[str, str], int] = {}

    def open(self) -> CounterSession:
        """Open every (channel, event); on failure close what was opened and re-raise."""
        try:
            for channel in self._channels:
                for event in self._events:
                    self._handles[(channel.name, event.name)] = self._reader.open(
                        channel.pmu_type, event.config, channel.cpu)
        except OSError:
            self.close()
            raise
        return self

    def read(self) -> Snapshot:
        """One reading per channel and event."""
        snapshot: Snapshot = {}
        for (channel, event), handle in self._handles.items():
            snapshot.setdefault(channel, {})[event] = self._reader.read(handle)
        return snapshot

    def role_deltas(self, before: Snapshot, after: Snapshot,
                    width_bits: int = PERF_COUNT_BITS) -> dict[str, dict[str, float]]:
        """Channel → role → counted delta between two snapshots (NaN where unknown)."""
        result: dict[str, dict[str, float]] = {}
        for channel, readings in after.items():
            deltas = window_deltas(before.get(channel, {}), readings, width_bits)
            result[channel] = {role: role_total(deltas, names) for role, names in self._roles.items()}
        return result

    def close(self) -> None:
        """Close every open event (idempotent)."""
        handles, self._handles = self._handles, {}
        for handle in handles.values():
            self._reader.close(handle)

    @property
    def open_events(self) -> Mapping[tuple[str, str], int]:
        """(channel, event) → handle of the open events."""
        return dict(self._handles)
