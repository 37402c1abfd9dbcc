"""What a host would count: its IMC PMUs, channels and encoded events — or why it cannot count.

:func:`plan_host` joins the pieces (sysfs PMUs, CPU generation, event table, permissions) into one
immutable :class:`HostPlan`; the ``hdeem-watch counters`` command prints it and the counter source
opens exactly its :attr:`HostPlan.events` on its :attr:`HostPlan.channels`. Everything is read from
injected paths, so the plan of a Haswell-EP or Ice Lake-SP host is tested on fixture trees.

Example:
    >>> plan = plan_host(sysfs_root="/nonexistent", cpuinfo_text="vendor_id: X\\ncpu family: 1\\nmodel: 1\\n")
    >>> plan.usable
    False
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hdeem_watch.counters.cpu_identity import DEFAULT_CPUINFO, CpuIdentity, generation_of, parse_cpuinfo
from hdeem_watch.counters.event_format import encode_event
from hdeem_watch.counters.event_tables import MAX_CKE_RANKS, TABLES, EventTable
from hdeem_watch.counters.permissions import PerfAccess, probe_access
from hdeem_watch.counters.pmu_discovery import (
    DEFAULT_SYSFS_ROOT,
    UncorePmu,
    discover_imc_pmus,
    is_memory_pmu,
    list_pmus,
)
from hdeem_watch.errors import InputError

#: Generic counters per IMC channel box (``num_counters = 4`` of the kernel's IMC uncore types).
GENERIC_COUNTERS_PER_BOX = 4


@dataclass(frozen=True)
class PlannedChannel:
    """One memory channel to count: a (socket, box) pair.

    Attributes:
        name: ``S<socket>.imc<box>``.
        socket: socket index (position of ``cpu`` in the PMU's ``cpumask``).
        box: the PMU's box index (channel position within the socket).
        pmu: PMU name, e.g. ``uncore_imc_4``.
        pmu_type: ``perf_event_attr.type``.
        cpu: the CPU to open the events on (counts that socket).
    """

    name: str
    socket: int
    box: int
    pmu: str
    pmu_type: int
    cpu: int


@dataclass(frozen=True)
class PlannedEvent:
    """One event, encoded with the PMUs' ``format/`` fields.

    Attributes:
        role: what it counts for the model (:data:`~hdeem_watch.counters.event_tables.ROLES`).
        name: Intel's event name.
        event: event code.
        umask: unit mask.
        config: the ``perf_event_attr.config`` word.
        experimental: from Intel's experimental event file.
        perf_alias: the kernel's own name for the same encoding in the PMU's ``events/`` (what ``perf
            list`` shows, e.g. ``cas_count_read``), ``None`` when it has none.
    """

    role: str
    name: str
    event: int
    umask: int
    config: int
    experimental: bool
    perf_alias: str | None = None
    mask_field: str = "umask"


@dataclass(frozen=True)
class HostPlan:
    """Everything ``hdeem-watch counters`` reports about a host.

    Attributes:
        cpu: the CPU identity (``None`` when cpuinfo could not be read).
        generation: the event-table key (``None``: no table for this CPU).
        table: the generation's event table.
        pmus: every IMC PMU found (programmable and free-running).
        other_pmus: names of the other PMUs the kernel registered (context for "no IMC PMU").
        channels: channels to count (empty without an event table or programmable IMC PMU).
        events: events per channel (same condition; listed even when permissions forbid opening them).
        access: the permission verdict.
        reasons: why counting cannot work here (empty when :attr:`usable`).
        notes: facts worth knowing even when usable (multiplexing, gaps).
    """

    cpu: CpuIdentity | None
    generation: str | None
    table: EventTable | None
    pmus: tuple[UncorePmu, ...]
    other_pmus: tuple[str, ...]
    channels: tuple[PlannedChannel, ...]
    events: tuple[PlannedEvent, ...]
    access: PerfAccess
    reasons: tuple[str, ...]
    notes: tuple[str, ...] = field(default=())

    @property
    def usable(self) -> bool:
        """True when the channels and events can be opened (as far as can be told without opening)."""
        return not self.reasons

    def to_dict(self) -> dict[str, Any]:
        """The ``--json`` object."""
        return {
            "usable": self.usable,
            "reasons": list(self.reasons),
            "notes": list(self.notes),
            "cpu": None if self.cpu is None else {
                "vendor": self.cpu.vendor, "family": self.cpu.family, "model": self.cpu.model,
                "stepping": self.cpu.stepping, "model_name": self.cpu.model_name,
                "signature": self.cpu.signature()},
            "generation": self.generation,
            "generation_title": None if self.table is None else self.table.title,
            "event_sources": [] if self.table is None else list(self.table.sources),
            "refresh_complete": None if self.table is None else self.table.refresh_complete,
            "gaps": [] if self.table is None else list(self.table.gaps),
            "pmus": [{"name": p.name, "type": p.pmu_type, "box": p.box, "free_running": p.free_running,
                      "cpumask": list(p.cpus), "formats": {k: v.describe() for k, v in sorted(p.formats.items())},
                      "events": list(p.events)}
                     for p in self.pmus],
            "other_pmus": list(self.other_pmus),
            "channels": [{"name": c.name, "socket": c.socket, "box": c.box, "pmu": c.pmu, "type": c.pmu_type,
                          "cpu": c.cpu} for c in self.channels],
            "events": [{"role": e.role, "name": e.name, "event": e.event, "umask": e.umask,
                        "config": f"{e.config:#x}", "experimental": e.experimental, "perf_alias": e.perf_alias,
                        "mask_field": e.mask_field}
                       for e in self.events],
            "permissions": {"perf_event_paranoid": self.access.paranoid, "cap_perfmon": self.access.cap_perfmon,
                            "cap_sys_admin": self.access.cap_sys_admin, "allowed": self.access.allowed,
                            "explanation": self.access.explanation},
        }


def encode_table(table: EventTable, pmu: UncorePmu, ranks: int | None = None) -> tuple[PlannedEvent, ...]:
    """Every (role, event) of ``table`` encoded with ``pmu``'s format fields.

    Args:
        table: the generation's events.
        pmu: the PMU whose ``format/`` fields encode them.
        ranks: ranks per channel: CKE residency is counted for ranks ``0..ranks-1`` only (``None``:
            every rank the table publishes).

    Raises:
        InputError: the PMU lacks the ``event``/``umask`` fields or a value does not fit them.
    """
    planned = []
    skipped = set() if ranks is None else {f"cke_on_rank{n}" for n in range(ranks, MAX_CKE_RANKS)}
    for role, events in table.roles.items():
        if role in skipped:
            continue
        for event in events:
            try:
                words = encode_event(pmu.formats, event.fields())
            except InputError as error:
                raise InputError(f"{pmu.name}: cannot encode {event.name}: {error}") from None
            planned.append(PlannedEvent(role=role, name=event.name, event=event.event, umask=event.umask,
                                        config=words["config"], experimental=event.experimental,
                                        perf_alias=pmu.alias_of(event.fields()), mask_field=event.mask_field))
    return tuple(planned)


def umc_channels(pmus: Sequence[UncorePmu]) -> tuple[PlannedChannel, ...]:
    """AMD: one channel per ``amd_umc_<n>`` PMU; its socket is the rank of its counting CPU among the PMUs'."""
    owners = sorted({p.cpus[0] for p in pmus if p.cpus})
    return tuple(sorted((PlannedChannel(name=f"S{owners.index(p.cpus[0])}.umc{p.box}", socket=owners.index(p.cpus[0]),
                                        box=p.box, pmu=p.name, pmu_type=p.pmu_type, cpu=p.cpus[0])
                         for p in pmus if p.cpus), key=lambda c: (c.socket, c.box)))


def channels_of(pmus: list[UncorePmu] | tuple[UncorePmu, ...]) -> tuple[PlannedChannel, ...]:
    """One channel per (socket, programmable PMU), socket-major, boxes ascending (AMD: :func:`umc_channels`)."""
    if any(p.umc for p in pmus):
        return umc_channels([p for p in pmus if p.umc])
    programmable = [p for p in pmus if not p.free_running]
    sockets = max((len(p.cpus) for p in programmable), default=0)
    return tuple(PlannedChannel(name=f"S{socket}.imc{p.box}", socket=socket, box=p.box, pmu=p.name,
                                pmu_type=p.pmu_type, cpu=p.cpus[socket])
                 for socket in range(sockets) for p in programmable if socket < len(p.cpus))


def free_running_note(pmus: Sequence[UncorePmu]) -> str | None:
    """What the ``uncore_imc_free_running_*`` PMUs count, as their ``events/`` name it, and why they are
    not used (``None``: there are none)."""
    free = [p for p in pmus if p.free_running]
    if not free:
        return None
    events = sorted({e for p in free for e in p.events})
    counted = ", ".join(events) if events else "no event aliases listed"
    return (f"{len(free)} uncore_imc_free_running_* PMU(s), one per controller ({counted}) are listed but not "
            "used: they have no ACT/PRE/power-state events")


def plan_host(sysfs_root: str | Path = DEFAULT_SYSFS_ROOT, cpuinfo_text: str | None = None,
              cpuinfo_path: str | Path = DEFAULT_CPUINFO, access: PerfAccess | None = None,
              ranks: int | None = None) -> HostPlan:
    """The counting plan of a host described by a sysfs root and a cpuinfo.

    Args:
        sysfs_root: the directory that holds ``bus/event_source/devices``.
        cpuinfo_text: ``/proc/cpuinfo`` content; read from ``cpuinfo_path`` when ``None``.
        cpuinfo_path: used when ``cpuinfo_text`` is ``None``.
        access: the permission verdict; probed from ``/proc`` when ``None``.
        ranks: ranks per channel (limits the CKE-residency events; ``None``: all the table has).

    Raises:
        InputError: a malformed PMU directory or cpuinfo.
    """
    if cpuinfo_text is None:
        try:
            cpuinfo_text = Path(cpuinfo_path).read_text()
        except OSError as error:
            raise InputError(f"{cpuinfo_path}: cannot read ({error.strerror})") from None
    cpu = parse_cpuinfo(cpuinfo_text, where=str(cpuinfo_path))
    generation = generation_of(cpu)
    table = TABLES.get(generation) if generation else None
    access = probe_access() if access is None else access
    pmus = tuple(discover_imc_pmus(sysfs_root))
    all_names = list_pmus(sysfs_root)
    others = tuple(n for n in all_names if not is_memory_pmu(n))
    reasons: list[str] = []
    notes: list[str] = []
    prefix = table.pmu_prefix if table is not None else ("amd_umc" if cpu.vendor == "AuthenticAMD" else "uncore_imc")
    programmable = [p for p in pmus if not p.free_running and p.name.startswith(prefix + "_")]
    if not all_names:
        reasons.append(f"{Path(sysfs_root) / 'bus/event_source/devices'} does not exist or is empty: "
                       "no perf_event PMUs are visible (not Linux, or sysfs not mounted)")
    elif not programmable:
        seen = ", ".join(others) if others else "none"
        driver = ("the amd_uncore driver with UMC support (PerfMonV2, Zen 4 and later)" if prefix == "amd_umc"
                  else "the intel_uncore driver")
        reasons.append(f"no {prefix}_* PMU: the kernel exposes no memory-controller counters here "
                       f"(PMUs present: {seen}). Virtual machines and containers on VMs do not get the "
                       f"host's uncore PMUs; run on the bare-metal node with {driver} loaded")
    if table is None:
        reasons.append(f"no IMC event table for CPU {cpu.signature()} ({cpu.model_name or 'unnamed'}); "
                       f"tables exist for: {', '.join(t.title for t in TABLES.values())}")
    if ranks is not None and not 1 <= ranks <= MAX_CKE_RANKS:
        raise InputError(f"ranks = {ranks}: expected 1..{MAX_CKE_RANKS} ranks per channel")
    if not access.allowed:
        reasons.append(f"permissions: {access.explanation}")
    events: tuple[PlannedEvent, ...] = ()
    if table is not None and programmable:
        encoded = {encode_table(table, p, ranks) for p in programmable}
        if len(encoded) != 1:
            raise InputError("the uncore_imc_* PMUs define different format fields; expected identical ones")
        events = encoded.pop()
        distinct = len({e.name for e in events})
        if distinct > GENERIC_COUNTERS_PER_BOX:
            notes.append(f"{distinct} events per channel on {GENERIC_COUNTERS_PER_BOX} counters: the kernel "
                         "multiplexes them; counts are scaled by time_enabled/time_running per window")
        notes.extend(f"gap: {gap}" for gap in table.gaps)
        notes.extend(table.notes)
        if (note := free_running_note(pmus)) is not None:
            notes.append(note)
    return HostPlan(cpu=cpu, generation=generation, table=table, pmus=pmus, other_pmus=others,
                    channels=channels_of(programmable) if events else (), events=events,
                    access=access, reasons=tuple(reasons), notes=tuple(notes))
