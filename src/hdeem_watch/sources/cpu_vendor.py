"""What a CPU can tell about DRAM energy, from ``/proc/cpuinfo``: the honest "no DRAM energy" message.

RAPL's DRAM domain exists on Intel *server* parts (Xeon E5/E7 from Haswell-EP on, Xeon Scalable,
Xeon Phi): the kernel lists it per model (drivers/powercap/intel_rapl_common.c, ``rapl_ids``: the
``rapl_defaults_hsw_server`` / ``_spr_server`` entries have the dram domain; client parts have
package/core/uncore/psys). AMD exposes package and core energy only — Zen's RAPL MSRs have no DRAM
domain (the kernel's amd_energy/amd RAPL support: ``power/energy-pkg`` and core energy) — on EPYC
servers as much as on Ryzen. So the message says what is true for the CPU at hand.

Example:
    >>> info = parse_cpuinfo("vendor_id\\t: AuthenticAMD\\ncpu family\\t: 25\\nmodel name\\t: AMD EPYC 7763 64-Core Processor\\n")
    >>> no_dram_reason(info).startswith("this AMD CPU (AMD EPYC 7763")
    True
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

CPUINFO = "/proc/cpuinfo"
ALTERNATIVES = "use the hdeem source on HDEEM nodes, or replay a recording"


@dataclass(frozen=True)
class CpuInfo:
    """The first processor's identity: ``vendor_id``, ``cpu family``, ``model``, ``model name``."""

    vendor: str
    family: int | None
    model: int | None
    model_name: str

    @property
    def server(self) -> bool:
        """An Intel server part by its name (Xeon, except the E3 / E-2xxx / W desktop-class ones)."""
        name = self.model_name.lower()
        if "xeon" not in name:
            return False
        return not any(mark in name for mark in (" e3-", " e-2", " w-"))


def parse_cpuinfo(text: str) -> CpuInfo:
    """The first processor block of ``/proc/cpuinfo`` text."""
    fields: dict[str, str] = {}
    for line in text.splitlines():
        if not line.strip():
            if fields:
                break
            continue
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())

    def number(key: str) -> int | None:
        try:
            return int(fields[key])
        except (KeyError, ValueError):
            return None

    return CpuInfo(fields.get("vendor_id", ""), number("cpu family"), number("model"), fields.get("model name", ""))


def read_cpuinfo(path: str | Path = CPUINFO) -> CpuInfo | None:
    """:func:`parse_cpuinfo` of ``path``; None if it cannot be read."""
    try:
        return parse_cpuinfo(Path(path).read_text(errors="replace"))
    except OSError:
        return None


def no_dram_reason(info: CpuInfo | None) -> str:
    """Why there is no RAPL DRAM energy on this CPU, and what to use instead."""
    if info is None:
        return f"cannot read {CPUINFO} to tell why; {ALTERNATIVES}"
    name = info.model_name or f"family {info.family} model {info.model}"
    if info.vendor == "AuthenticAMD" or info.vendor == "HygonGenuine":
        return (f"this AMD CPU ({name}) exposes no DRAM energy: AMD's RAPL has package and core domains "
                f"only, on EPYC servers too; {ALTERNATIVES}")
    if info.vendor == "GenuineIntel":
        if info.server:
            return (f"this Intel server CPU ({name}) normally has a DRAM domain: check that the BIOS enables "
                    "DRAM RAPL and that intel_rapl_msr (intel_rapl_tpmi on Granite Rapids and later) is loaded; else "
                    + ALTERNATIVES)
        return f"this Intel client CPU ({name}) exposes no DRAM energy (client parts have no DRAM domain); {ALTERNATIVES}"
    return f"this CPU ({info.vendor or 'unknown vendor'}, {name}) exposes no DRAM energy through RAPL; {ALTERNATIVES}"
