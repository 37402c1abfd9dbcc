"""The counter-reading port: open a raw PMU event on a CPU, read it with its enabled/running times.

:class:`CounterReader` is the narrow interface the counter code needs from the operating system. Its
real implementation is a thin adapter over the project's ctypes ``perf_event_open`` wrapper
(``hdeem_watch.perf_event``; :class:`~hdeem_watch.counters.perf_reader.PerfCounterReader`): ``open`` fills ``perf_event_attr`` with ``type = pmu_type``,
``config/config1/config2``, ``read_format = PERF_FORMAT_TOTAL_TIME_ENABLED |
PERF_FORMAT_TOTAL_TIME_RUNNING`` and calls ``perf_event_open(attr, pid=-1, cpu, group_fd=-1,
flags=PERF_FLAG_FD_CLOEXEC)``; ``read`` reads the three u64 words; ``close`` closes the fd. Errors
are :class:`OSError` with the syscall's errno (``EACCES``/``EPERM``: permissions, see
:mod:`hdeem_watch.counters.permissions`; ``ENOENT``/``EINVAL``/``ENODEV``: the event or PMU does not
exist here).

:class:`FakeCounterReader` stands in for hardware that does not exist in CI: it mimics the
documented behaviour (``perf_event_open(2)``): the count accrues only while the event runs, the
times grow with an injected clock, and a multiplexed event runs a fixed share of the time.

Example:
    >>> clock = iter([0, 1_000]).__next__
    >>> fake = FakeCounterReader(lambda t, c, cpu, ns: ns // 10, clock=clock, running_share=0.5)
    >>> h = fake.open(13, 0x304, 0)
    >>> fake.read(h)
    Reading(value=50, time_enabled_ns=1000, time_running_ns=500)
"""

from __future__ import annotations

import errno
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from hdeem_watch.counters.arithmetic import PERF_COUNT_BITS, Reading


class CounterReader(Protocol):
    """Open, read and close raw PMU events (the ``perf_event_open`` port)."""

    def open(self, pmu_type: int, config: int, cpu: int, config1: int = 0, config2: int = 0) -> int:
        """Open event ``config`` of PMU ``pmu_type`` CPU-wide on ``cpu``; return a handle.

        Raises:
            OSError: with the syscall's errno.
        """
        ...

    def read(self, handle: int) -> Reading:
        """The event's count and its enabled/running times so far."""
        ...

    def close(self, handle: int) -> None:
        """Release the event."""
        ...


#: ``truth(pmu_type, config, cpu, elapsed_ns) -> count``: what the event would have counted in
#: ``elapsed_ns`` had it run all the time.
TruthFunction = Callable[[int, int, int, int], int]


@dataclass
class _FakeEvent:
    pmu_type: int
    config: int
    cpu: int
    opened_ns: int


class FakeCounterReader:
    """A :class:`CounterReader` over a truth function, with multiplexing and a counter width.

    Args:
        truth: the full count of an event after ``elapsed_ns`` (see :data:`TruthFunction`).
        clock: monotonic nanoseconds (injected).
        running_share: fraction of the enabled time each event is on a counter (1.0: no
            multiplexing).
        known_types: PMU types that exist (``open`` of another fails with ``ENOENT``, as the kernel
            does); ``None`` accepts any.
        denied: ``open`` fails with ``EACCES`` (an unprivileged process, ``perf_event_paranoid > 0``).
        width_bits: the reported value wraps at ``2**width_bits``.
    """

    def __init__(self, truth: TruthFunction, clock: Callable[[], int] = time.monotonic_ns,
                 running_share: float = 1.0, known_types: frozenset[int] | None = None,
                 denied: bool = False, width_bits: int = PERF_COUNT_BITS) -> None:
        if not 0.0 < running_share <= 1.0:
            raise ValueError(f"running_share = {running_share}; expected 0 < share <= 1")
        self._truth = truth
        self._clock = clock
        self._share = running_share
        self._known = known_types
        self._denied = denied
        self._mask = (1 << width_bits) - 1
        self._events: dict[int, _FakeEvent] = {}
        self._next = 3

    def open(self, pmu_type: int, config: int, cpu: int, config1: int = 0, config2: int = 0) -> int:
        """Open an event (see :meth:`CounterReader.open`)."""
        if self._denied:
            raise OSError(errno.EACCES, os.strerror(errno.EACCES))
        if self._known is not None and pmu_type not in self._known:
            raise OSError(errno.ENOENT, os.strerror(errno.ENOENT))
        handle = self._next
        self._next += 1
        self._events[handle] = _FakeEvent(pmu_type, config, cpu, self._clock())
        return handle

    def read(self, handle: int) -> Reading:
        """Count and times so far (see :meth:`CounterReader.read`)."""
        event = self._events.get(handle)
        if event is None:
            raise OSError(errno.EBADF, os.strerror(errno.EBADF))
        enabled = self._clock() - event.opened_ns
        running = int(enabled * self._share)
        counted = int(self._truth(event.pmu_type, event.config, event.cpu, enabled) * self._share)
        return Reading(counted & self._mask, enabled, running)

    def close(self, handle: int) -> None:
        """Forget the event (closing twice is an error, as for a file descriptor)."""
        if self._events.pop(handle, None) is None:
            raise OSError(errno.EBADF, os.strerror(errno.EBADF))

    @property
    def open_handles(self) -> int:
        """How many events are open (tests check that every open is closed)."""
        return len(self._events)
