"""``dmidecode -t 17`` (SMBIOS Memory Device) text → one record per DIMM slot.

The text is dmidecode's own print-out: records start ``Handle 0x...., DMI type 17, N bytes``, then
a title line ``Memory Device`` and tab-indented ``Key: Value`` lines. Spellings of dmidecode
versions are all read: ``Size: 8192 MB`` (< 3.0) or ``8 GB``; ``Speed: 2133 MHz`` (< 3.0) or
``MT/s``; ``Configured Clock Speed`` (< 3.2) or ``Configured Memory Speed``. An empty slot says
``Size: No Module Installed``.

Example:
    >>> text = '''Handle 0x0030, DMI type 17, 40 bytes
    ... Memory Device
    ... \\tData Width: 64 bits
    ... \\tSize: 8192 MB
    ... \\tLocator: DIMM_A1
    ... \\tType: DDR4
    ... \\tSpeed: 2133 MHz
    ... \\tPart Number: M393A1G43DB0-CPB\\x20\\x20
    ... \\tRank: 2
    ... '''
    >>> d = parse_dmidecode(text)[0]
    >>> d.locator, d.size_bytes, d.speed_mts, d.ranks, d.part_number
    ('DIMM_A1', 8589934592, 2133, 2, 'M393A1G43DB0-CPB')
"""

from __future__ import annotations

import re
from dataclasses import dataclass

_UNITS = {"KB": 1 << 10, "kB": 1 << 10, "MB": 1 << 20, "GB": 1 << 30, "TB": 1 << 40}
_NOT_SET = {"", "not specified", "unknown", "not provided", "none", "no dimm", "[empty]", "empty",
            "not installed", "0000", "undefined"}


@dataclass(frozen=True)
class MemoryDevice:
    """One DMI type 17 record (a DIMM slot).

    Attributes:
        handle: the record handle (``0x0030``).
        locator: ``Locator`` (the slot's silk-screen name).
        bank_locator: ``Bank Locator`` (often socket/channel on server boards).
        size_bytes: module size, ``None`` for an empty slot or an unknown size.
        type: ``Type`` (``DDR4``), ``None`` unknown.
        type_detail: ``Type Detail`` (``Synchronous Registered (Buffered)``).
        speed_mts: rated ``Speed`` in MT/s.
        configured_mts: ``Configured Memory Speed`` / ``Configured Clock Speed`` in MT/s.
        ranks: ``Rank``.
        data_width: ``Data Width`` in bits (64 without ECC bits).
        total_width: ``Total Width`` in bits (72 with ECC).
        manufacturer: ``Manufacturer``.
        part_number: ``Part Number`` (trailing blanks removed).
    """

    handle: str
    locator: str
    bank_locator: str | None
    size_bytes: int | None
    type: str | None
    type_detail: str | None
    speed_mts: int | None
    configured_mts: int | None
    ranks: int | None
    data_width: int | None
    total_width: int | None
    manufacturer: str | None
    part_number: str | None

    @property
    def installed(self) -> bool:
        """A module is in the slot."""
        return self.size_bytes is not None and self.size_bytes > 0


def _text(value: str | None) -> str | None:
    if value is None:
        return None
    value = value.strip()
    return None if value.lower() in _NOT_SET else value


def _int(value: str | None, pattern: str = r"(\d+)") -> int | None:
    text = _text(value)
    if text is None:
        return None
    match = re.match(pattern, text)
    return int(match.group(1)) if match else None


def _size(value: str | None) -> int | None:
    text = _text(value)
    if text is None or "no module" in text.lower():
        return None
    match = re.fullmatch(r"(\d+)\s*(kB|KB|MB|GB|TB)", text)
    return int(match.group(1)) * _UNITS[match.group(2)] if match else None


def parse_dmidecode(text: str) -> list[MemoryDevice]:
    """Every ``Memory Device`` record of a dmidecode print-out, in print order (empty slots too).

    Args:
        text: the output of ``dmidecode -t 17`` (or of ``dmidecode``: other types are skipped).
    """
    devices: list[MemoryDevice] = []
    for block in re.split(r"\n(?=Handle 0x)", text.replace("\r\n", "\n")):
        header = re.match(r"Handle (0x[0-9A-Fa-f]+), DMI type (\d+)", block)
        if header is None or header.group(2) != "17":
            continue
        fields: dict[str, str] = {}
        for line in block.splitlines()[1:]:
            if line.startswith("\t") and not line.startswith("\t\t") and ":" in line:
                key, _, value = line.strip().partition(":")
                fields[key.strip()] = value.strip()
        configured = fields.get("Configured Memory Speed", fields.get("Configured Clock Speed"))
        devices.append(MemoryDevice(
            handle=header.group(1),
            locator=fields.get("Locator", "").strip(),
            bank_locator=_text(fields.get("Bank Locator")),
            size_bytes=_size(fields.get("Size")),
            type=_text(fields.get("Type")),
            type_detail=_text(fields.get("Type Detail")),
            speed_mts=_int(fields.get("Speed")),
            configured_mts=_int(configured),
            ranks=_int(fields.get("Rank")),
            data_width=_int(fields.get("Data Width")),
            total_width=_int(fields.get("Total Width")),
            manufacturer=_text(fields.get("Manufacturer")),
            part_number=_text(fields.get("Part Number")),
        ))
    return devices
