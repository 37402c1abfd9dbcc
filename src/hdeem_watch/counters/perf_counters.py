"""The host's memory-controller counters through ``perf_event_open`` (``counters = "perf"``).

:class:`PerfCounters` opens the host plan's events
(:class:`~hdeem_watch.counters.perf_reader.PerfCounterReader`); each read's per-event deltas are
scaled for multiplexing and summed per role (:class:`~hdeem_watch.counters.source.RoleTotals`).
:func:`imc_sensors` says which DRAM power channel measures each IMC channel.
"""

from __future__ import annotations

import errno
from collections.abc import Callable
from typing import Any

from hdeem_watch.channels import dimm_pair_channel
from hdeem_watch.counters.source import CounterChannel, CounterSnapshot, RoleTotals
from hdeem_watch.errors import InputError


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


