"""The DDR generation of a DIMM when dmidecode's ``Type`` does not say it (``Other``, ``Unknown``).

Some BIOSes print ``Type: Other`` for DDR4 modules (a public capture of a Supermicro X10DRL-i with
two Xeon E5-2695 v3 and Samsung M393A1G40DB0-CPB RDIMMs). Two other facts say DDR4:

- the module part number's family prefix: Samsung ``M3xxA``/``M4xxA`` (``M393A`` RDIMM, ``M386A``
  LRDIMM, ``M378A``/``M391A`` UDIMM, ``M471A``/``M474A`` SODIMM; ``…B`` is DDR3, ``M321R`` DDR5),
  SK hynix ``HMA`` (``HMT`` DDR3, ``HMC`` DDR5), Micron ``MTA<n>A…`` (``<n>ASF`` RDIMM, ``<n>ATF``
  UDIMM, ``<n>ADF``; dmidecode often drops the ``MTA``; ``KSF``/``JSF`` are DDR3); DDR5 modules:
  Samsung ``M3xxR``/``M4xxR`` (``M321R`` RDIMM), SK hynix ``HMC``, Micron ``MTC<n>F…``
  (``MTC20F2085S1RC48BA1`` 32 GB 2Rx8 RDIMM);
- the CPU generation: the memory controller of Xeon E5 v3/v4 and of Xeon Scalable up to Ice
  Lake-SP drives DDR4 only (:mod:`.cpu_model`).

Example:
    >>> infer_ddr("Other", "M393A1G40DB0-CPB", None)
    ('DDR4', 'memory type Other read as DDR4: part number M393A1G40DB0-CPB is a Samsung DDR4 module (M3xxA)')
    >>> infer_ddr("DDR4", "M393A1G40DB0-CPB", None)
    ('DDR4', None)
"""

from __future__ import annotations

import re

from hdeem_watch.node.cpu_model import CpuModel, memory_controller

_PART_FAMILIES: tuple[tuple[re.Pattern[str], str, str], ...] = (
    (re.compile(r"M[34]\d\dA\d"), "DDR4", "a Samsung DDR4 module (M3xxA)"),
    (re.compile(r"HMA"), "DDR4", "an SK hynix DDR4 module (HMA)"),
    (re.compile(r"(?:MTA)?\d{1,2}A[SDT]F"), "DDR4", "a Micron DDR4 module (MTA<n>A…)"),
    (re.compile(r"M[34]\d\dB\d|HMT|(?:MT)?\d{1,2}[KJ][SDT]F"), "DDR3", "a DDR3 module"),
    (re.compile(r"M[34]\d\dR\d"), "DDR5", "a Samsung DDR5 module (M3xxR)"),
    (re.compile(r"HMC"), "DDR5", "an SK hynix DDR5 module (HMC)"),
    (re.compile(r"MTC\d{1,2}F"), "DDR5", "a Micron DDR5 module (MTC<n>F…)"),
)
#: dmidecode ``Type`` values that name no DDR generation.
UNTOLD = {"other", "unknown", "dram", "sdram"}


def ddr_from_part_number(part: str | None) -> tuple[str, str] | None:
    """``(DDR generation, why)`` from a module part number's family prefix, ``None`` unknown."""
    text = (part or "").strip().upper()
    for pattern, ddr, why in _PART_FAMILIES:
        if pattern.match(text):
            return ddr, f"part number {part} is {why}"
    return None


def infer_ddr(told: str | None, part: str | None, cpu: CpuModel | None) -> tuple[str | None, str | None]:
    """The DIMMs' DDR generation and, when it was inferred, why (one clause for the memspec reason).

    ``told`` is dmidecode's ``Type``; a real generation there is kept as is. Otherwise the part
    number and the CPU's memory controller each may say it; they are named together when they agree.
    """
    if told is not None and told.lower() not in UNTOLD:
        return told, None
    reasons: list[str] = []
    ddr: str | None = None
    by_part = ddr_from_part_number(part)
    if by_part is not None:
        ddr = by_part[0]
        reasons.append(by_part[1])
    controller = memory_controller(cpu)
    if cpu is not None and controller is not None and len(controller.memory_types) == 1:
        only = controller.memory_types[0]
        if ddr is None or ddr == only:
            ddr = only
            reasons.append(f"{cpu.name} ({controller.generation}) drives {only} only")
    if ddr is None:
        return told, None
    return ddr, f"memory type {told or 'unknown'} read as {ddr}: " + "; ".join(reasons)
