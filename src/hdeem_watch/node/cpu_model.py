"""Which CPU the node has, and what its memory controller drives (channels per socket, DDR types).

The CPU is read from ``/proc/cpuinfo`` (``model name``, ``cpu family``, ``model``) or, for a saved
print-out, from dmidecode's Processor Information records (type 4: ``Version`` and ``Signature:
Type 0, Family 6, Model 63, Stepping 2``). What the memory controller is comes from Intel's and
AMD's product documentation:

- Xeon E5-2600/4600 v3 (Haswell-EP, family 6 model 63) and v4 (Broadwell-EP, model 79): 4 DDR4
  channels per socket, DDR4 only (the E7 v3/v4 parts of the same models also drive DDR3 through
  memory buffers, so only the E5 names are matched);
- Xeon Scalable 1st/2nd generation (Skylake-SP/Cascade Lake-SP, model 85): 2 IMCs × 3 channels =
  6 DDR4 channels; 3rd generation (Ice Lake-SP, models 106/108): 4 IMCs × 2 = 8 DDR4 channels;
  4th generation (Sapphire Rapids, model 143) and 5th (Emerald Rapids, model 207): 8 DDR5 channels;
- Xeon 6 with P-cores (Granite Rapids, model 173): 12 DDR5 channels on the 6900P parts, 8 on the
  6700P/6500P parts (the model number does not tell them apart, so the name is matched);
- AMD EPYC 7xx1/7xx2/7xx3 (Naples, Rome, Milan): 8 DDR4 channels; EPYC 9xx4 (Genoa, family 25
  model 17) and 9xx5 (Turin, family 26 model 2): 12 DDR5 channels; EPYC 8xx4 (Siena): 6 DDR5 channels.

:func:`is_amd` tells AMD parts apart: they have no DRAM energy sensor (RAPL on AMD has package and core
domains only), so the node's DRAM energy is modelled from the ``amd_umc`` counters there.

Example:
    >>> cpu = cpu_from_cpuinfo("vendor_id : GenuineIntel\\ncpu family : 6\\nmodel : 63\\n"
    ...                        "model name : Intel(R) Xeon(R) CPU E5-2680 v3 @ 2.50GHz\\n")
    >>> memory_controller(cpu)
    MemoryController(generation='Haswell-EP', channels_per_socket=4, memory_types=('DDR4',))
"""

from __future__ import annotations

import re
from dataclasses import dataclass


@dataclass(frozen=True)
class CpuModel:
    """The node's CPU as one source names it.

    Attributes:
        name: the model name (``Intel(R) Xeon(R) Gold 6148 CPU @ 2.40GHz``).
        family: CPU family, ``None`` unknown.
        model: CPU model number, ``None`` unknown.
        source: where it was read (``/proc/cpuinfo``, ``dmidecode -t 4``).
    """

    name: str
    family: int | None
    model: int | None
    source: str


@dataclass(frozen=True)
class MemoryController:
    """What a CPU generation's memory controller drives, per socket."""

    generation: str
    channels_per_socket: int
    memory_types: tuple[str, ...]


_BY_NAME: tuple[tuple[re.Pattern[str], MemoryController], ...] = (
    (re.compile(r"\bE5-\d{4}\w*\s+v3\b"), MemoryController("Haswell-EP", 4, ("DDR4",))),
    (re.compile(r"\bE5-\d{4}\w*\s+v4\b"), MemoryController("Broadwell-EP", 4, ("DDR4",))),
    (re.compile(r"\bEPYC\s+7\d\d[123]\w*\b"), MemoryController("EPYC 7001-7003", 8, ("DDR4",))),
    (re.compile(r"\bEPYC\s+9\d\d4\w*\b"), MemoryController("Genoa (EPYC 9004)", 12, ("DDR5",))),
    (re.compile(r"\bEPYC\s+9\d\d5\w*\b"), MemoryController("Turin (EPYC 9005)", 12, ("DDR5",))),
    (re.compile(r"\bEPYC\s+8\d\d4\w*\b"), MemoryController("Siena (EPYC 8004)", 6, ("DDR5",))),
    (re.compile(r"\bXeon\(R\)\s+69\d\d[A-Z]*\b"), MemoryController("Granite Rapids-AP (Xeon 6900P)", 12, ("DDR5",))),
    (re.compile(r"\bXeon\(R\)\s+6[5-7]\d\d[A-Z]*\b"), MemoryController("Granite Rapids-SP (Xeon 6700P/6500P)", 8,
                                                                    ("DDR5",))),
)
_BY_MODEL: dict[tuple[int, int], MemoryController] = {
    (6, 85): MemoryController("Skylake-SP/Cascade Lake-SP", 6, ("DDR4",)),
    (6, 106): MemoryController("Ice Lake-SP", 8, ("DDR4",)),
    (6, 108): MemoryController("Ice Lake-SP", 8, ("DDR4",)),
    (6, 143): MemoryController("Sapphire Rapids", 8, ("DDR5",)),
    (6, 207): MemoryController("Emerald Rapids", 8, ("DDR5",)),
    (25, 17): MemoryController("Genoa (EPYC 9004)", 12, ("DDR5",)),
    (26, 2): MemoryController("Turin (EPYC 9005)", 12, ("DDR5",)),
}


def is_amd(cpu: CpuModel | None) -> bool:
    """An AMD (or Hygon) processor: ``AMD`` in its name, or family 23 or later (Zen's families; Intel's are 6
    and 15)."""
    if cpu is None:
        return False
    return "AMD" in cpu.name.upper() or (cpu.family or 0) >= 23


def memory_controller(cpu: CpuModel | None) -> MemoryController | None:
    """The memory controller of ``cpu``'s generation, ``None`` when not in the table."""
    if cpu is None:
        return None
    for pattern, controller in _BY_NAME:
        if pattern.search(cpu.name):
            return controller
    if cpu.family is not None and cpu.model is not None:
        return _BY_MODEL.get((cpu.family, cpu.model))
    return None


def _field(text: str, key: str) -> str | None:
    match = re.search(rf"^{key}\s*:\s*(.+?)\s*$", text, re.M)
    return match.group(1) if match else None


def cpu_from_cpuinfo(text: str | None) -> CpuModel | None:
    """The first processor of a ``/proc/cpuinfo`` text, ``None`` without a ``model name``."""
    if not text:
        return None
    name = _field(text, "model name")
    if name is None:
        return None
    family, model = _field(text, "cpu family"), _field(text, "model")
    return CpuModel(name, int(family) if family and family.isdigit() else None,
                    int(model) if model and model.isdigit() else None, "/proc/cpuinfo")


def cpu_from_dmidecode(text: str | None) -> CpuModel | None:
    """The first populated Processor Information record (DMI type 4) of a dmidecode print-out."""
    for block in re.split(r"\n(?=Handle 0x)", (text or "").replace("\r\n", "\n")):
        if not re.match(r"Handle 0x[0-9A-Fa-f]+, DMI type 4\b", block):
            continue
        name = re.search(r"^\s*Version:\s*(.+?)\s*$", block, re.M)
        signature = re.search(r"Signature:.*Family (\d+), Model (\d+)", block)
        if name is None or name.group(1).lower() in ("not specified", ""):
            continue
        return CpuModel(name.group(1), int(signature.group(1)) if signature else None,
                        int(signature.group(2)) if signature else None, "dmidecode -t 4")
    return None
