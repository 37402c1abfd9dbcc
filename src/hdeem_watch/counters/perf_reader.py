"""The real :class:`~hdeem_watch.counters.reader.CounterReader`: ``perf_event_open`` through ctypes.

Each event is opened CPU-wide on the channel's socket CPU (``pid = -1``, ``cpu`` from the PMU's
``cpumask``), with ``read_format = PERF_FORMAT_TOTAL_TIME_ENABLED | PERF_FORMAT_TOTAL_TIME_RUNNING``,
enabled at once, without ``exclude_*`` bits or a sampling period (the uncore driver refuses both
with ``EINVAL``: ``uncore_pmu_event_init`` in arch/x86/events/intel/uncore.c). A read gives the
count and both times; the multiplexing scale and the wrap are the pure arithmetic's
(:mod:`hdeem_watch.counters.arithmetic`). Errors stay :class:`OSError` with the syscall's errno, so
the caller can tell permissions (``EACCES``/``EPERM``: :mod:`hdeem_watch.counters.permissions`
explains them) from a missing PMU or event (``ENOENT``/``ENODEV``/``EINVAL``).

``pid`` and ``exclude_kernel`` exist for core and software events of this process (tests run the
real syscall with a software event: a virtual machine has no uncore PMU).

Example (this process's task clock, allowed at the default ``perf_event_paranoid = 2``):
    >>> from hdeem_watch.perf_event import PERF_COUNT_SW_TASK_CLOCK, PERF_TYPE_SOFTWARE
    >>> reader = PerfCounterReader(pid=0, exclude_kernel=True)
    >>> handle = reader.open(PERF_TYPE_SOFTWARE, PERF_COUNT_SW_TASK_CLOCK, cpu=-1)  # doctest: +SKIP
    >>> reader.read(handle).time_enabled_ns > 0                                      # doctest: +SKIP
    True
"""

from __future__ import annotations

import errno
import os

from hdeem_watch.counters.arithmetic import Reading
from hdeem_watch.perf_event import PERF_FORMAT_TOTAL_TIME_ENABLED, PERF_FORMAT_TOTAL_TIME_RUNNING, PerfEvent

#: The read format of every counter: the count, the time enabled and the time running.
READ_FORMAT = PERF_FORMAT_TOTAL_TIME_ENABLED | PERF_FORMAT_TOTAL_TIME_RUNNING


class PerfCounterReader:
    """Opens, reads and closes raw PMU events with ``perf_event_open``.

    Args:
        pid: ``-1`` (default): count on ``cpu`` for every process (uncore events must be opened so);
            ``0``: this process only (core and software events).
        exclude_kernel: count user space only (for a process's own events at paranoid level 2;
            uncore PMUs refuse it).
    """

    def __init__(self, *, pid: int = -1, exclude_kernel: bool = False) -> None:
        self.pid = int(pid)
        self.exclude_kernel = bool(exclude_kernel)
        self._events: dict[int, PerfEvent] = {}

    def open(self, pmu_type: int, config: int, cpu: int, config1: int = 0, config2: int = 0) -> int:
        """Open one event; the handle is its file descriptor.

        Raises:
            OSError: the syscall's errno (EACCES/EPERM: not allowed; ENOENT/ENODEV/EINVAL: no such
                PMU or event).
        """
        event = PerfEvent.open(pmu_type, config, pid=self.pid, cpu=cpu, exclude_kernel=self.exclude_kernel,
                               config1=config1, config2=config2, read_format=READ_FORMAT)
        self._events[event.fd] = event
        return event.fd

    def read(self, handle: int) -> Reading:
        """The count and its enabled/running times so far."""
        event = self._events.get(handle)
        if event is None:
            raise OSError(errno.EBADF, os.strerror(errno.EBADF))
        value, enabled, running = event.read_times()
        return Reading(value, enabled, running)

    def close(self, handle: int) -> None:
        """Close the event (closing twice is an error, as for a file descriptor)."""
        event = self._events.pop(handle, None)
        if event is None:
            raise OSError(errno.EBADF, os.strerror(errno.EBADF))
        event.close()

    @property
    def open_handles(self) -> int:
        """How many events are open."""
        return len(self._events)
