"""RAPL DRAM energy through the kernel's ``power`` PMU (``perf stat -e power/energy-ram/``).

Where powercap's ``energy_uj`` is closed (root-only since CVE-2020-8694) the same counters are
reachable through perf, which has its own permission model: ``kernel.perf_event_paranoid`` <= 0, or
the capability ``CAP_PERFMON`` (Linux 5.8+; ``CAP_SYS_ADMIN`` before). The PMU is described in sysfs
(arch/x86/events/rapl.c; Documentation/ABI/testing/sysfs-bus-event_source-devices-*):

* ``/sys/bus/event_source/devices/power/type``: the PMU's dynamic type for ``perf_event_attr.type``;
* ``events/energy-ram``: the event's terms, e.g. ``event=0x03``, placed into ``config`` by the
  ``format/<term>`` files (``config:0-7``);
* ``events/energy-ram.scale`` (J per count, e.g. ``2.3283064365386962890625e-10``) and
  ``events/energy-ram.unit`` (``Joules``);
* ``cpumask``: one CPU per RAPL domain (package, or die on kernels that scope RAPL per die); an event
  is opened on each of them (``pid = -1, cpu = N``) and counts that socket's DRAM.

The socket of each CPU comes from ``/sys/devices/system/cpu/cpuN/topology/physical_package_id`` (and
``die_id``), so channels are named like powercap's: ``DRAM<X>`` or ``DRAM<X>_DIE<Y>``.
"""

from __future__ import annotations

import errno
from collections.abc import Callable
from pathlib import Path
from typing import Protocol

from hdeem_watch.perf_event import PerfEvent, PerfEventError, paranoid_level
from hdeem_watch.sources.base import SourceUnavailable
from hdeem_watch.sources.cpu_vendor import no_dram_reason, read_cpuinfo
from hdeem_watch.sources.rapl_zones import EnergyCounter, channel_name

PMU_DIR = "/sys/bus/event_source/devices/power"
CPU_DIR = "/sys/devices/system/cpu"
EVENT = "energy-ram"


class Counter(Protocol):
    """An open event: ``read()`` its count, ``close()`` it."""

    def read(self) -> int: ...

    def close(self) -> None: ...


Opener = Callable[[int, int, int], Counter]


def open_system_wide(type_: int, config: int, cpu: int) -> Counter:
    """The real opener: ``perf_event_open`` counting on ``cpu`` for every process."""
    return PerfEvent.open(type_, config, pid=-1, cpu=cpu)


def parse_cpu_list(text: str) -> list[int]:
    """``"0,24"`` or ``"0-3,8"`` → CPU numbers.

    >>> parse_cpu_list("0,24"), parse_cpu_list("0-2,8")
    ([0, 24], [0, 1, 2, 8])
    """
    cpus: list[int] = []
    for part in text.strip().split(","):
        if not part:
            continue
        lo, _, hi = part.partition("-")
        cpus.extend(range(int(lo), int(hi or lo) + 1))
    return cpus


def event_config(pmu: Path, terms: str) -> int:
    """The ``config`` word of an event string like ``event=0x03`` (fields placed by ``format/``).

    Raises:
        ValueError: a term whose format is not ``config:lo-hi`` / ``config:bit``.
    """
    config = 0
    for term in terms.strip().split(","):
        if not term:
            continue
        key, _, value = term.partition("=")
        spec = (pmu / "format" / key.strip()).read_text().strip() if (pmu / "format" / key.strip()).is_file() \
            else "config:0-63"
        field, _, bits = spec.partition(":")
        if field != "config":
            raise ValueError(f"{pmu}/format/{key}: {spec!r}; only config fields are supported")
        lo = int(bits.split("-")[0])
        config |= int(value or "1", 0) << lo
    return config


def _topology(cpu_dir: Path, cpu: int) -> tuple[int, int]:
    base = cpu_dir / f"cpu{cpu}" / "topology"
    package = int((base / "physical_package_id").read_text().strip())
    die_file = base / "die_id"
    die = int(die_file.read_text().strip()) if die_file.is_file() else 0
    return package, die


def _denied_reason(exc: OSError, paranoid: int | None) -> str:
    return (f"rapl: perf_event_open of power/{EVENT} denied ({exc.strerror}; perf_event_paranoid = "
            f"{paranoid if paranoid is not None else '?'}); set kernel.perf_event_paranoid = 0 (sysctl) or give "
            "the daemon CAP_PERFMON (AmbientCapabilities=CAP_PERFMON in the unit); under systemd also allow the "
            "system call (SystemCallFilter=perf_event_open: it is in @debug, not @system-service)")


def perf_counters(sysfs: str | Path = PMU_DIR, cpu_dir: str | Path = CPU_DIR, opener: Opener = open_system_wide,
                  cpuinfo: str | Path = "/proc/cpuinfo",
                  paranoid: Callable[[], int | None] = paranoid_level) -> tuple[list[EnergyCounter], Callable[[], None]]:
    """One counter per socket (or die) for ``power/energy-ram``, and a function closing them all.

    Raises:
        SourceUnavailable: no power PMU, no ``energy-ram`` event (the reason says what this CPU
            offers), an unexpected unit, or ``perf_event_open`` refused (with the fix).
    """
    pmu, cpus_root = Path(sysfs), Path(cpu_dir)
    if not (pmu / "type").is_file():
        raise SourceUnavailable(f"rapl: no power PMU at {pmu} (kernel without RAPL perf support, "
                                "or a virtual machine)")
    event = pmu / "events" / EVENT
    if not event.is_file():
        raise SourceUnavailable(f"rapl: the power PMU has no {EVENT} event: {no_dram_reason(read_cpuinfo(cpuinfo))}")
    try:
        type_ = int((pmu / "type").read_text().strip())
        config = event_config(pmu, event.read_text())
        scale_file = pmu / "events" / f"{EVENT}.scale"
        scale = float(scale_file.read_text().strip()) if scale_file.is_file() else 1.0
        unit_file = pmu / "events" / f"{EVENT}.unit"
        unit = unit_file.read_text().strip() if unit_file.is_file() else "Joules"
        cpus = parse_cpu_list((pmu / "cpumask").read_text())
        places = [_topology(cpus_root, cpu) for cpu in cpus]
    except (OSError, ValueError) as exc:
        raise SourceUnavailable(f"rapl: cannot read the power PMU's description under {pmu}: {exc}") from None
    if unit != "Joules" or not scale > 0:
        raise SourceUnavailable(f"rapl: power/{EVENT} counts in {unit!r} × {scale}; expected Joules")
    per_die = len({package for package, _ in places}) < len(places)
    opened: list[Counter] = []

    def close_all() -> None:
        for counter in opened:
            counter.close()
        opened.clear()

    counters = []
    for cpu, (package, die) in sorted(zip(cpus, places), key=lambda item: item[1]):
        try:
            event_fd = opener(type_, config, cpu)
        except OSError as exc:
            close_all()
            if exc.errno in (errno.EACCES, errno.EPERM):
                raise SourceUnavailable(_denied_reason(exc, paranoid())) from None
            raise SourceUnavailable(f"rapl: perf_event_open of power/{EVENT} on CPU {cpu}: {exc.strerror}") from None
        opened.append(event_fd)
        counters.append(EnergyCounter(channel_name(package, die if per_die else None), event_fd.read, scale, None))
    return counters, close_all


__all__ = ["PerfEventError", "event_config", "open_system_wide", "parse_cpu_list", "perf_counters"]
