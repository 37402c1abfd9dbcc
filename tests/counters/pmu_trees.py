"""Builds the perf PMU sysfs trees of the counter tests (``build(dest)``; once per test session into a
temporary directory, so the trees are not committed).

Each tree is ``<root>/bus/event_source/devices/<pmu>/{type,cpumask,format/*,events/*}`` as the
kernel lays it out (``Documentation/ABI/testing/sysfs-bus-event_source-devices-format`` and
``-events``); the facts behind each PMU are cited where they are tabled below and in
fixtures/README.md.

Usage: ``python3 tests/counters/pmu_trees.py DIR`` writes the trees into DIR (to look at them).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

#: ``snbep_uncore_formats_attr`` / ``skx_uncore_format_group`` (arch/x86/events/intel/uncore_snbep.c)
UNCORE_FORMAT = {"edge": "config:18", "event": "config:0-7", "inv": "config:23", "thresh": "config:24-31",
                 "umask": "config:8-15"}
#: the core PMU's format (arch/x86/events/intel/core.c, ``intel_arch3_formats_attr``)
CPU_FORMAT = {"any": "config:21", "cmask": "config:24-31", "edge": "config:18", "event": "config:0-7",
              "inv": "config:23", "pc": "config:19", "umask": "config:8-15"}
#: the free-running PMUs' format (``skx_uncore_iio_freerunning_format_group``: event and umask only)
FREE_RUNNING_FORMAT = {"event": "config:0-7", "umask": "config:8-15"}
#: 64 bytes per CAS in MiB (the kernel's ``.scale`` of ``cas_count_*``)
CAS_SCALE = {"scale": "6.103515625e-5", "unit": "MiB"}


@dataclass(frozen=True)
class Pmu:
    """One PMU directory: its dynamic ``type`` number, ``cpumask`` (None: no file), format fields and
    events (name → encoding, with optional ``.scale``/``.unit`` companions)."""

    name: str
    type: int
    cpumask: str | None = None
    format: dict[str, str] = field(default_factory=dict)
    events: dict[str, str] = field(default_factory=dict)
    units: dict[str, dict[str, str]] = field(default_factory=dict)


def _plain(type_numbers: dict[str, int]) -> list[Pmu]:
    """Software PMUs with only a ``type`` file."""
    return [Pmu(name, number) for name, number in type_numbers.items()]


def _host_common(cpus: str, per_socket: str) -> list[Pmu]:
    """The PMUs every Intel host shows besides the uncore ones (so that discovery must pick the IMC ones)."""
    return [*_plain({"software": 1, "tracepoint": 2, "breakpoint": 5}),
            Pmu("cpu", 4, cpus, CPU_FORMAT),
            Pmu("msr", 6, None, {"event": "config:0-63"}),
            Pmu("power", 7, per_socket, {"event": "config:0-7"})]


def _imc(box: int, type_number: int, cpumask: str, read_umask: str, write_umask: str) -> Pmu:
    events = {"cas_count_read": f"event=0x04,umask={read_umask}", "cas_count_write": f"event=0x04,umask={write_umask}",
              "clockticks": "event=0x00,umask=0x00"}
    return Pmu(f"uncore_imc_{box}", type_number, cpumask, UNCORE_FORMAT, events,
               {"cas_count_read": CAS_SCALE, "cas_count_write": CAS_SCALE})


def haswell_ep() -> list[Pmu]:
    """Two Xeon E5-2680 v3 (HT off: CPUs 0-11, 12-23). ``hswep_uncore_imc`` has 8 boxes (MC0 ch0-3 →
    0-3, MC1 ch0-3 → 4-7); the 12-core die's two home agents with two channels each register boxes
    0, 1, 4, 5. Events: ``hswep_uncore_imc_events`` (cas read umask 0x03, write 0x0c)."""
    boxes = [_imc(box, 10 + i, "0,12", "0x03", "0x0c") for i, box in enumerate((0, 1, 4, 5))]
    home_agents = [Pmu(f"uncore_ha_{i}", 8 + i, "0,12", UNCORE_FORMAT) for i in range(2)]
    return [*_host_common("0-23", "0,12"), *home_agents, *boxes]


def ice_lake_sp() -> list[Pmu]:
    """Two Xeon Platinum 8358 (HT off: CPUs 0-31, 32-63). ``icx_uncore_imc``: 12 boxes (4 controllers
    × ``ICX_NUMBER_IMC_CHN`` 3), events ``snr_uncore_imc_events`` (cas read umask 0x0f, write 0x30);
    ``icx_uncore_imc_free_running``: one box per controller with ``icx_uncore_imc_freerunning_events``
    (``dclk``, DDR ``read``/``write`` and Optane DCPMM ``ddrt_read``/``ddrt_write``, bandwidth in MiB)."""
    boxes = [_imc(box, 20 + box, "0,32", "0x0f", "0x30") for box in range(12)]
    events = {"dclk": "event=0xff,umask=0x10", "read": "event=0xff,umask=0x20", "write": "event=0xff,umask=0x21",
              "ddrt_read": "event=0xff,umask=0x30", "ddrt_write": "event=0xff,umask=0x31"}
    free = [Pmu(f"uncore_imc_free_running_{i}", 40 + i, "0,32", FREE_RUNNING_FORMAT, events,
                {name: CAS_SCALE for name in events if name != "dclk"})
            for i in range(4)]
    return [*_host_common("0-63", "0,32"), *boxes, *free]


#: ``spr_uncore_raw_formats_attr`` (uncore_snbep.c): ``umask_ext4`` puts the umask in config:8-15,32-55
SPR_FORMAT = {"edge": "config:18", "event": "config:0-7", "inv": "config:23", "thresh": "config:24-31",
              "umask": "config:8-15,32-55"}
#: ``spr_uncore_imc_events`` (Linux commit of lore.kernel.org 20230419214241.2310385-1-eranian@google.com):
#: ``clockticks`` is event 0x01 umask 0x00, which perfmon names UNC_M_HCLOCKTICKS (not the DCLK 0x01/0x01)
SPR_IMC_EVENTS = {"clockticks": "event=0x01,umask=0x00", "cas_count_read": "event=0x05,umask=0xcf",
                  "cas_count_write": "event=0x05,umask=0xf0"}


def sapphire_rapids() -> list[Pmu]:
    """Two Xeon Platinum 8480+ (56 cores, HT off: CPUs 0-55, 56-111). Programmable IMC PMUs
    ``uncore_imc_0..7`` (``spr_uncore_imc``, one box per channel: 4 controllers x 2 channels on the
    XCC die, numbered from the uncore discovery table), format ``spr_uncore_raw_format_group``, events
    :data:`SPR_IMC_EVENTS`; and the free-running ones ``spr_uncore_imc_free_running`` (one per
    controller, 4 per socket) with ``spr_uncore_imc_freerunning_events``: ``dclk`` and the read/write
    pending-queue cycles ``rpq_cycles``, ``wpq_cycles`` (no bandwidth events)."""
    boxes = [Pmu(f"uncore_imc_{box}", 50 + box, "0,56", SPR_FORMAT, SPR_IMC_EVENTS,
                 {"cas_count_read": CAS_SCALE, "cas_count_write": CAS_SCALE}) for box in range(8)]
    events = {"dclk": "event=0xff,umask=0x10", "rpq_cycles": "event=0xff,umask=0x20",
              "wpq_cycles": "event=0xff,umask=0x21"}
    free = [Pmu(f"uncore_imc_free_running_{i}", 60 + i, "0,56", FREE_RUNNING_FORMAT, events) for i in range(4)]
    return [*_host_common("0-111", "0,56"), *boxes, *free]


#: ``amd_uncore_umc_format_attr`` (arch/x86/events/amd/uncore.c): ``event8`` and ``rdwrmask``
UMC_FORMAT = {"event": "config:0-7", "rdwrmask": "config:8-9"}


def genoa() -> list[Pmu]:
    """Two AMD EPYC 9654 (96 cores, SMT off: CPUs 0-95, 96-191), NPS1. ``amd_umc_0..23``: the UMC PMUs
    ``amd_uncore_umc_ctx_init`` registers, one per active UMC (12 per socket), numbered across the two
    groups (sockets); each PMU's ``cpumask`` is the one CPU counting its group (0 or 96); format
    :data:`UMC_FORMAT`, no ``events/``. Besides: ``amd_df`` and ``amd_l3`` (the other amd_uncore PMUs,
    format ``event`` config:0-7,32-35 and ``umask`` config:8-15 on family 19h), the core ``cpu`` PMU and
    ``power`` (package energy only)."""
    umcs = [Pmu(f"amd_umc_{i}", 30 + i, "0" if i < 12 else "96", UMC_FORMAT) for i in range(24)]
    df = {"event": "config:0-7,32-35", "umask": "config:8-15"}
    return [*_plain({"software": 1, "tracepoint": 2, "breakpoint": 5}),
            Pmu("cpu", 4, "0-191", {"edge": "config:18", "event": "config:0-7,32-35", "inv": "config:23",
                                     "cmask": "config:24-31", "umask": "config:8-15"}),
            Pmu("msr", 6, None, {"event": "config:0-63"}),
            Pmu("power", 7, "0,96", {"event": "config:0-7"}, {"energy-pkg": "event=0x02"}),
            Pmu("amd_df", 8, "0,96", df), Pmu("amd_l3", 9, "0,96", df), *umcs]


def vm() -> list[Pmu]:
    """This KVM guest's own ``/sys/bus/event_source/devices`` (2026-11-25): no ``cpu``, no uncore PMU."""
    return [*_plain({"software": 1, "tracepoint": 2, "breakpoint": 5}),
            Pmu("uprobe", 8, None, {"ref_ctr_offset": "config:32-63", "retprobe": "config:0"}),
            Pmu("msr", 9, None, {"event": "config:0-63"})]


TREES = {"sysfs_haswell_ep": haswell_ep, "sysfs_ice_lake_sp": ice_lake_sp, "sysfs_sapphire_rapids": sapphire_rapids,
         "sysfs_genoa": genoa, "sysfs_vm": vm}


def _write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text + "\n")


def write_pmu(devices: Path, pmu: Pmu) -> None:
    """One PMU directory under ``devices``."""
    base = devices / pmu.name
    _write(base / "type", str(pmu.type))
    if pmu.cpumask is not None:
        _write(base / "cpumask", pmu.cpumask)
    for key, bits in pmu.format.items():
        _write(base / "format" / key, bits)
    for event, encoding in pmu.events.items():
        _write(base / "events" / event, encoding)
        for suffix, value in pmu.units.get(event, {}).items():
            _write(base / "events" / f"{event}.{suffix}", value)


def build(dest: Path) -> Path:
    """Write every tree (``dest/sysfs_<host>/bus/event_source/devices/...``); returns ``dest``."""
    for name, pmus in TREES.items():
        devices = dest / name / "bus" / "event_source" / "devices"
        for pmu in pmus():
            write_pmu(devices, pmu)
    return dest


if __name__ == "__main__":
    build(Path(sys.argv[1]))
