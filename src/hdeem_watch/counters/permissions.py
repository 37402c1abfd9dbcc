"""May this process open uncore IMC events? ``perf_event_paranoid`` and ``CAP_PERFMON``, explained.

Uncore PMUs count for a whole socket, so their events are CPU-wide (``pid = -1, cpu = N``); the
kernel allows those to an unprivileged process only when ``/proc/sys/kernel/perf_event_paranoid``
is ``<= 0`` (Linux ``Documentation/admin-guide/perf-security.rst``: -1 no restriction, 0 CPU events
allowed, 1 no CPU events, 2 (default) no kernel profiling either; Debian/Ubuntu kernels add 3/4:
nothing at all). Otherwise the process needs ``CAP_PERFMON`` (Linux >= 5.8) or ``CAP_SYS_ADMIN`` in
its effective set (``CapEff`` of ``/proc/self/status``).

Example:
    >>> check_access(paranoid=2, capabilities=0).allowed
    False
    >>> check_access(paranoid=2, capabilities=1 << CAP_PERFMON).allowed
    True
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

DEFAULT_PARANOID_PATH = "/proc/sys/kernel/perf_event_paranoid"
DEFAULT_STATUS_PATH = "/proc/self/status"
#: Capability numbers (include/uapi/linux/capability.h).
CAP_SYS_ADMIN = 21
CAP_PERFMON = 38

FIX = ("grant the collector CAP_PERFMON (e.g. AmbientCapabilities=CAP_PERFMON in its systemd unit, "
       "or setcap cap_perfmon+ep on its interpreter), or set kernel.perf_event_paranoid=0 "
       "(sysctl; allows every user CPU-wide events)")


@dataclass(frozen=True)
class PerfAccess:
    """The verdict on CPU-wide perf events for this process.

    Attributes:
        paranoid: ``perf_event_paranoid`` (``None`` when unreadable).
        cap_perfmon: ``CAP_PERFMON`` is effective (``None`` when unknown).
        cap_sys_admin: ``CAP_SYS_ADMIN`` is effective (``None`` when unknown).
        allowed: uncore events can be opened (as far as permissions go).
        explanation: one sentence for the user, with the fix when not allowed.
    """

    paranoid: int | None
    cap_perfmon: bool | None
    cap_sys_admin: bool | None
    allowed: bool
    explanation: str


def check_access(paranoid: int | None, capabilities: int | None) -> PerfAccess:
    """Pure verdict from the paranoid level and the effective capability mask."""
    perfmon = None if capabilities is None else bool(capabilities >> CAP_PERFMON & 1)
    admin = None if capabilities is None else bool(capabilities >> CAP_SYS_ADMIN & 1)
    level = "unknown" if paranoid is None else str(paranoid)
    if perfmon or admin:
        held = "CAP_PERFMON" if perfmon else "CAP_SYS_ADMIN"
        return PerfAccess(paranoid, perfmon, admin, True,
                          f"allowed: the process holds {held} (perf_event_paranoid = {level} does not apply)")
    if paranoid is not None and paranoid <= 0:
        return PerfAccess(paranoid, perfmon, admin, True,
                          f"allowed: perf_event_paranoid = {paranoid} permits CPU-wide events to every user")
    caps = "unknown capabilities" if capabilities is None else "neither CAP_PERFMON nor CAP_SYS_ADMIN"
    return PerfAccess(paranoid, perfmon, admin, False,
                      f"not allowed: perf_event_paranoid = {level} (> 0 forbids CPU-wide events such as uncore "
                      f"counters to unprivileged processes) and the process holds {caps}; fix: {FIX}")


def read_paranoid(path: str | Path = DEFAULT_PARANOID_PATH) -> int | None:
    """``perf_event_paranoid``, or ``None`` when the file is absent or unreadable."""
    try:
        return int(Path(path).read_text().strip())
    except (OSError, ValueError):
        return None


def read_effective_capabilities(path: str | Path = DEFAULT_STATUS_PATH) -> int | None:
    """The ``CapEff`` mask of a ``/proc/<pid>/status`` file, or ``None`` when it is not there."""
    try:
        for line in Path(path).read_text().splitlines():
            if line.startswith("CapEff:"):
                return int(line.split(":", 1)[1].strip(), 16)
    except (OSError, ValueError):
        return None
    return None


def probe_access(paranoid_path: str | Path = DEFAULT_PARANOID_PATH,
                 status_path: str | Path = DEFAULT_STATUS_PATH) -> PerfAccess:
    """:func:`check_access` for this process (paths injected for tests)."""
    return check_access(read_paranoid(paranoid_path), read_effective_capabilities(status_path))
