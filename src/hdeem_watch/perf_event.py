"""``perf_event_open(2)`` through ctypes: open a counting event, read its 64-bit count, close it.

Only counting mode (no sampling, no ring buffer): the event's value is read with ``read(2)`` as one
``u64`` (``read_format = 0``), or with ``read_format = PERF_FORMAT_TOTAL_TIME_ENABLED |
PERF_FORMAT_TOTAL_TIME_RUNNING`` as three: the count and the nanoseconds the event was enabled and
actually on a counter (:meth:`PerfEvent.read_times`; the kernel multiplexes events when a PMU has
more events than counters). The attribute struct is the first, stable 64 bytes of
``struct perf_event_attr`` (``PERF_ATTR_SIZE_VER0``, include/uapi/linux/perf_event.h), which every
kernel accepts, or 72 (``PERF_ATTR_SIZE_VER1``) when ``config2`` is used.

This module sits below ``sources`` (RAPL's ``power/energy-ram``) and ``counters`` (the uncore IMC
PMUs), which both use it.

Example (counting this process's own CPU time, allowed at the default perf_event_paranoid = 2):
    >>> event = PerfEvent.open(PERF_TYPE_SOFTWARE, PERF_COUNT_SW_TASK_CLOCK, pid=0, cpu=-1,
    ...                        exclude_kernel=True)        # doctest: +SKIP
    >>> event.read() > 0                                   # doctest: +SKIP
    True
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import os
import platform
import struct
from pathlib import Path

PERF_TYPE_HARDWARE, PERF_TYPE_SOFTWARE = 0, 1
PERF_COUNT_SW_CPU_CLOCK, PERF_COUNT_SW_TASK_CLOCK = 0, 1
PERF_FLAG_FD_CLOEXEC = 1 << 3
PERF_ATTR_SIZE_VER0 = 64
PERF_ATTR_SIZE_VER1 = 72
#: ``read_format`` bits: the enabled and running times follow the value.
PERF_FORMAT_TOTAL_TIME_ENABLED, PERF_FORMAT_TOTAL_TIME_RUNNING = 1 << 0, 1 << 1
#: ``struct perf_event_attr`` flag bits (the bitfield after ``read_format``).
_DISABLED, _INHERIT, _EXCLUDE_USER, _EXCLUDE_KERNEL, _EXCLUDE_HV = 1 << 0, 1 << 1, 1 << 4, 1 << 5, 1 << 6
#: ``__NR_perf_event_open`` per architecture.
SYSCALL_NUMBERS = {"x86_64": 298, "i386": 336, "i686": 336, "aarch64": 241, "arm64": 241, "riscv64": 241,
                   "ppc64le": 319, "ppc64": 319, "s390x": 331, "armv7l": 364, "loongarch64": 241}
PARANOID = "/proc/sys/kernel/perf_event_paranoid"


class PerfEventAttr(ctypes.Structure):
    """The first 72 bytes of ``struct perf_event_attr`` (``PERF_ATTR_SIZE_VER1``; ``size`` says how
    many the kernel reads)."""

    _fields_ = [
        ("type", ctypes.c_uint32),
        ("size", ctypes.c_uint32),
        ("config", ctypes.c_uint64),
        ("sample_period", ctypes.c_uint64),
        ("sample_type", ctypes.c_uint64),
        ("read_format", ctypes.c_uint64),
        ("flags", ctypes.c_uint64),
        ("wakeup_events", ctypes.c_uint32),
        ("bp_type", ctypes.c_uint32),
        ("config1", ctypes.c_uint64),
        ("config2", ctypes.c_uint64),
    ]


class PerfEventError(OSError):
    """``perf_event_open`` failed; ``errno`` says why (EACCES/EPERM: not allowed)."""


def paranoid_level(path: str | Path = PARANOID) -> int | None:
    """``kernel.perf_event_paranoid`` (None if it cannot be read)."""
    try:
        return int(Path(path).read_text().strip())
    except (OSError, ValueError):
        return None


def _syscall():  # type: ignore[no-untyped-def]
    libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
    fn = libc.syscall
    fn.restype = ctypes.c_long
    return fn


class PerfEvent:
    """An open counting event (a file descriptor); use :meth:`open`."""

    def __init__(self, fd: int, read_format: int = 0) -> None:
        self.fd = fd
        self.read_format = read_format

    @classmethod
    def open(cls, type_: int, config: int, *, pid: int = -1, cpu: int = -1, exclude_kernel: bool = False,
             exclude_hv: bool = False, config1: int = 0, config2: int = 0, read_format: int = 0) -> PerfEvent:
        """``perf_event_open`` of a counting event.

        Args:
            type_: PMU type (``PERF_TYPE_SOFTWARE``, or a dynamic PMU's ``type`` from sysfs).
            config: the event's config word.
            pid, cpu: ``pid=0, cpu=-1`` counts this process; ``pid=-1, cpu=N`` counts CPU N (or its
                package, for uncore-like PMUs such as ``power``) system-wide.
            exclude_kernel, exclude_hv: count user space only (needed at paranoid level 2 for a
                process's own events; the power and uncore PMUs refuse any exclude bit).
            config1, config2: the extra config words (filters of some uncore events).
            read_format: ``PERF_FORMAT_TOTAL_TIME_*`` bits for :meth:`read_times` (0: :meth:`read`).

        Raises:
            PerfEventError: the syscall failed (errno set), or the architecture is unknown.
        """
        number = SYSCALL_NUMBERS.get(platform.machine())
        if number is None:
            raise PerfEventError(errno.ENOSYS, f"perf_event_open: unknown architecture {platform.machine()}")
        attr = PerfEventAttr()
        attr.type = type_
        attr.size = PERF_ATTR_SIZE_VER1 if config2 else PERF_ATTR_SIZE_VER0
        attr.config = config
        attr.config1 = config1
        attr.config2 = config2
        attr.read_format = read_format
        attr.flags = (_EXCLUDE_KERNEL if exclude_kernel else 0) | (_EXCLUDE_HV if exclude_hv else 0)
        fd = _syscall()(number, ctypes.byref(attr), pid, cpu, -1, PERF_FLAG_FD_CLOEXEC)
        if fd < 0:
            err = ctypes.get_errno()
            raise PerfEventError(err, f"perf_event_open(type={type_}, config={config:#x}, pid={pid}, cpu={cpu}): "
                                 f"{os.strerror(err)}")
        return cls(int(fd), read_format)

    def read(self) -> int:
        """The event's count so far (u64)."""
        return self.read_times()[0]

    def read_times(self) -> tuple[int, int, int]:
        """``(count, time enabled ns, time running ns)``; the times are 0 unless the event was opened
        with the matching ``read_format`` bits."""
        words = 1 + bin(self.read_format & (PERF_FORMAT_TOTAL_TIME_ENABLED | PERF_FORMAT_TOTAL_TIME_RUNNING)).count("1")
        data = os.read(self.fd, 8 * words)
        if len(data) != 8 * words:
            raise OSError(errno.EIO, f"perf event read returned {len(data)} bytes, expected {8 * words}")
        values = list(struct.unpack(f"={words}Q", data))
        enabled = values.pop(1) if self.read_format & PERF_FORMAT_TOTAL_TIME_ENABLED else 0
        running = values.pop(1) if self.read_format & PERF_FORMAT_TOTAL_TIME_RUNNING else 0
        return int(values[0]), int(enabled), int(running)

    def close(self) -> None:
        """Close the descriptor (idempotent)."""
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1
