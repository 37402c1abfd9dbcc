"""Which memspec fits the node's DIMMs: a known part number, else the nearest preset.

1. The part number is looked up in :data:`KNOWN_MODULES` (module → preset, exact die).
2. Else die density and device width are worked out (device width from EDAC or the part number's
   organisation code; density = size · 8 / (ranks · 64/width) Gbit) and the nearest preset by
   (same type, same density, same width, closest speed) is taken, with a confidence:
   ``exact`` (part number known), ``high`` (density, width and speed bin match), ``medium``
   (density and width match, another speed bin), ``low`` (anything else: a stand-in).

:func:`for_dimm` re-shapes the chosen preset to the DIMM's ranks and devices per rank.

Example:
    >>> from hdeem_watch.node.description import Dimm
    >>> dimm = Dimm("P1-DIMMA1", size_bytes=8 << 30, type="DDR4", speed_mts=2133, ranks=2, total_width=72,
    ...             part_number="M393A1G43DB0-CPB")
    >>> choice = choose_memspec([dimm])
    >>> choice.name, choice.confidence
    ('samsung-m393a1g43db0-cpb', 'exact')
"""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

from hdeem_watch.dram.presets import PRESET_INFO
from hdeem_watch.node.cpu_model import CpuModel
from hdeem_watch.node.description import Dimm
from hdeem_watch.node.memory_type import infer_ddr

#: Module part numbers (upper case, speed suffix included) → preset with the same die.
KNOWN_MODULES: dict[str, str] = {
    "M393A1G43DB0-CPB": "samsung-m393a1g43db0-cpb",
    "MTA18ASF2G72HZ-2G3B1": "micron-8gb-x8-ddr4-2400-b",
    "MTA18ASF2G72PDZ-2G3B1": "micron-8gb-x8-ddr4-2400-b",
    "MTA9ASF1G72PZ-2G3B1": "micron-8gb-x8-ddr4-2400-b",    # 8 GB 1Rx8, the same B die
    "MTA36ASF4G72PZ-2G3B1": "micron-8gb-x4-ddr4-2400-b",   # 32 GB 2Rx4, the x4 organisation of that die
}


@dataclass(frozen=True)
class MemspecChoice:
    """The memspec chosen for the node's DIMMs.

    Attributes:
        name: a preset name (``None``: nothing fits, e.g. DDR5, for which no preset exists).
        reason: why (one line).
        confidence: ``exact``, ``high``, ``medium``, ``low`` or ``none``.
        die_gbit: die density worked out for the DIMMs (``None`` unknown).
        device_width: device width worked out (``None`` unknown).
        ranks: ranks of the DIMMs (for :func:`for_dimm`; ``None`` unknown).
        devices_per_rank: devices per rank, ECC devices included (``None`` unknown).
    """

    name: str | None
    reason: str
    confidence: str
    die_gbit: int | None = None
    device_width: int | None = None
    ranks: int | None = None
    devices_per_rank: int | None = None

    def to_json(self) -> dict[str, Any]:
        """``{"name", "reason", "confidence", "die_gbit", "device_width", "ranks", "devices_per_rank"}``."""
        return {"name": self.name, "reason": self.reason, "confidence": self.confidence,
                "die_gbit": self.die_gbit, "device_width": self.device_width, "ranks": self.ranks,
                "devices_per_rank": self.devices_per_rank}


def width_from_part_number(part: str, ranks: int | None) -> int | None:
    """Device width from a module part number's organisation code (Samsung, SK hynix, Micron DDR4;
    Micron DDR5 ``MTC<devices>F…``).

    Samsung ``M393A1G43...``: ``43`` x8, ``40`` x4; SK hynix ``HMA82GR7AFR8N``: ``R8`` x8, ``R4`` x4;
    Micron ``MTA18ASF...``: devices per module with the ranks (18 devices, 2 ranks → x8).
    """
    text = part.upper()
    if m := re.match(r"M3\d\dA\d?[0-9A-Z]{2}(4[03B])", text):
        return {"40": 4, "43": 8, "4B": 4}[m.group(1)]
    if m := re.match(r"HMA\w+?R7\w\w(R[48])N", text):
        return int(m.group(1)[1])
    if (m := re.match(r"MTA(\d+)A", text)) and ranks:
        devices = int(m.group(1))
        per_rank = devices / ranks
        return {18.0: 4, 9.0: 8, 8.0: 8, 16.0: 4, 4.0: 16}.get(per_rank)
    if (m := re.match(r"MTC(\d+)F", text)) and ranks:   # DDR5: two 32-bit sub-channels (+ 4 or 8 ECC bits each)
        per_rank = int(m.group(1)) / ranks
        return {20.0: 4, 10.0: 8, 16.0: 4, 8.0: 8, 4.0: 16}.get(per_rank)
    return None


def die_gbit(dimm: Dimm, width: int | None) -> int | None:
    """Die density in Gbit from size, ranks and device width (64 data bits per rank)."""
    if not (dimm.size_bytes and dimm.ranks and width):
        return None
    devices = dimm.ranks * (64 // width)
    gbit = dimm.size_bytes * 8 / devices / (1 << 30)
    return int(gbit) if gbit >= 1 and float(gbit).is_integer() else None


#: Die densities no preset has: the nearest preset is only the calibration's prior there. No complete
#: public per-die IDD table of a 16 Gb DDR4 die was found (Micron MT40A1G16 rev D publishes IDD0, IPP0,
#: IDD1, IDD2N, IDD2NT and IDD2P only).
PRIOR_ONLY_GBIT = 16


def choose_memspec(dimms: Sequence[Dimm], *, cpu: CpuModel | None = None) -> MemspecChoice:
    """The preset for the node's DIMMs (the most common kind when they differ).

    Args:
        dimms: the node's DIMMs.
        cpu: the node's CPU, to read a DDR generation dmidecode does not name (``Type: Other``).
    """
    if not dimms:
        return MemspecChoice(None, "no DIMM detected; set memspec in the [node] table (or the daemon's --memspec)", "none")
    kinds = Counter((d.part_number, d.type, d.speed_mts, d.size_bytes, d.ranks, d.device_width) for d in dimms)
    part, mem_type, speed, _size, ranks, width = kinds.most_common(1)[0][0]
    dimm = next(d for d in dimms if (d.part_number, d.type, d.speed_mts) == (part, mem_type, speed))
    mixed = f" ({len(kinds)} kinds of DIMM; the most common one used)" if len(kinds) > 1 else ""
    if part and part.strip().upper() in KNOWN_MODULES:
        name = KNOWN_MODULES[part.strip().upper()]
        info = PRESET_INFO[name]
        return MemspecChoice(name, f"part number {part} is a known module ({info.die}){mixed}", "exact",
                             info.die_gbit, info.width, ranks, devices_per_rank(dimm, info.width))
    mem_type, inferred = infer_ddr(mem_type, part, cpu)
    width = width or (width_from_part_number(part, ranks) if part else None)
    density = die_gbit(dimm, width)
    rate = dimm.configured_mts or speed
    if mem_type is not None and mem_type.upper() == "DDR5":
        why = ddr5_reason(rate, density, width) + (f" ({inferred})" if inferred else "") + mixed
        return MemspecChoice(None, why, "none", density, width, ranks, devices_per_rank(dimm, width))
    if mem_type is not None and mem_type.upper() != "DDR4":
        return MemspecChoice(None, f"memory type {mem_type}: only DDR4 presets exist{mixed}", "none")

    def score(name: str) -> tuple[int, int, int]:
        info = PRESET_INFO[name]
        return (int(density is not None and info.die_gbit != density), int(width is not None and info.width != width),
                abs(info.speed_mts - rate) if rate else 0)

    best = min(sorted(PRESET_INFO), key=score)
    info = PRESET_INFO[best]
    missing = [what for what, value in (("die density", density), ("device width", width), ("speed", rate))
               if value is None]
    mismatched = [what for what, differs in (("die density", density is not None and info.die_gbit != density),
                                             ("device width", width is not None and info.width != width),
                                             ("speed", rate is not None and info.speed_mts != rate)) if differs]
    if not missing and not mismatched:
        confidence = "high"
    elif not missing and mismatched == ["speed"]:
        confidence = "medium"
    else:
        confidence = "low"
    told = f"{mem_type or 'DDR4?'} {rate or '?'} MT/s, {density or '?'} Gb x{width or '?'} dies"
    why = f"nearest preset to {told} ({info.die}, {info.speed_mts} MT/s)"
    if inferred:
        why = f"{inferred}; {why}"
    if density is not None and density >= PRIOR_ONLY_GBIT:
        why += (f"; {density} Gb dies have no preset (no complete public IDD table): {best} is only the "
                f"calibration's prior, the calibration fits this node's currents")
    if missing:
        why += f"; unknown: {', '.join(missing)}"
    if mismatched:
        why += f"; differs in {', '.join(mismatched)}"
    if part:
        why += f"; part number {part} not in the known-module table"
    return MemspecChoice(best, why + mixed, confidence, density, width, ranks, devices_per_rank(dimm, width))


#: The DDR5 memspec the repository ships: DRAMPower's own DDR5 test memspec (a worked example, not a
#: datasheet of any module).
DDR5_EXAMPLE = "examples/ddr5_drampower_test.json"


def ddr5_reason(rate: int | None, density: int | None, width: int | None) -> str:
    """Why no memspec is chosen for DDR5 DIMMs, and the way in (a DDR5 memspec file)."""
    told = f"DDR5 {rate or '?'} MT/s, {density or '?'} Gb x{width or '?'} dies"
    return (f"memory type DDR5 ({told}): there is no DDR5 preset: no public, complete IDD/IPP table of a "
            f"DDR5 die exists to build one from, and no number is invented; give a DDR5 memspec file in "
            f"DRAMPower's JSON with --memspec FILE (daemon, model commands) or memspec = \"FILE\" in the [node] table "
            f"({DDR5_EXAMPLE} is DRAMPower's DDR5 test memspec: a format example, not this DIMM's currents)")


def for_dimm(spec: Any, ranks: int | None, devices_per_rank: int | None) -> Any:
    """``spec`` (a :class:`~hdeem_watch.dram.memspec.MemSpec`) with the DIMM's ranks and devices per rank."""
    changes = {k: v for k, v in (("nbr_of_ranks", ranks), ("nbr_of_devices", devices_per_rank)) if v}
    return replace(spec, **changes)


def devices_per_rank(dimm: Dimm, width: int | None) -> int | None:
    """Devices per rank: total bus width (72 with ECC) / device width."""
    bus = dimm.total_width or dimm.data_width
    return bus // width if bus and width else None
