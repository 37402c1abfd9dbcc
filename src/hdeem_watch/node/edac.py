"""DIMMs as the kernel's EDAC drivers show them under ``/sys/devices/system/edac/mc``.

Per memory controller ``mcN``: ``dimmM/`` directories (Linux >= 3.5, only populated slots) with
``size`` (MB), ``dimm_label``, ``dimm_location`` (e.g. ``channel 2 slot 0`` or ``csrow 1 channel 0``),
``dimm_mem_type`` (``Registered-DDR4``), ``dimm_dev_type`` (``x8``), ``dimm_edac_mode`` (kernel
``Documentation/ABI/testing/sysfs-devices-edac``, ``/sys/devices/system/edac/mc/mc*/(dimm|rank)*``).
A chip-select based driver (``mci->csbased``: one of its layers is ``EDAC_MC_LAYER_CHIP_SELECT``,
e.g. amd64_edac) names the same directories ``rankM/``, one per populated rank, and ``rank*/size`` is
one rank's size; its location reads ``csrow C channel H`` and its default label ``mc#0csrow#1channel#3``
(drivers/edac/edac_mc.c, edac_mc_sysfs.c). Chip selects 2k and 2k+1 of a channel are the two ranks of
its DIMM k (amd64_edac), so ranks are joined into DIMMs that way. Older kernels have only ``csrowK/``
with ``size_mb``, ``mem_type``, ``dev_type`` and ``chJ_dimm_label`` (one csrow per rank).

Example:
    >>> parse_location_text("channel 2 slot 0 ")
    {'channel': 2, 'slot': 0}
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from pathlib import Path

SYSFS_ROOT = Path("/sys")


@dataclass(frozen=True)
class EdacDimm:
    """One DIMM (or, on csrow kernels, one rank) of an EDAC memory controller.

    Attributes:
        mc: the controller number (``mcN``).
        name: the sysfs directory name (``dimm3`` or ``csrow1``).
        label: ``dimm_label`` (the driver's default or a label registered by ras-mc-ctl).
        location: ``dimm_location`` parsed into layer name → index.
        size_mb: size in MB.
        mem_type: ``Registered-DDR4`` etc.
        dev_type: device width (``x4``, ``x8``), ``None`` when the driver does not know.
        edac_mode: ``SECDED``, ``S4ECD4ED``, ...
        ranks: ranks joined into this DIMM (from ``rank*/`` directories), ``None`` when not told.
    """

    mc: int
    name: str
    label: str
    location: dict[str, int]
    size_mb: int | None
    mem_type: str | None
    dev_type: str | None
    edac_mode: str | None
    ranks: int | None = None


def parse_location_text(text: str) -> dict[str, int]:
    """``dimm_location`` (``"branch 0 channel 1 slot 0"``) as layer name → index."""
    tokens = text.split()
    out: dict[str, int] = {}
    for name, value in zip(tokens[0::2], tokens[1::2], strict=False):
        if value.isdigit():
            out[name] = int(value)
    return out


def _read(path: Path) -> str | None:
    try:
        text = path.read_text(encoding="utf-8").strip()
    except OSError:
        return None
    return text or None


def _int(text: str | None) -> int | None:
    return int(text) if text is not None and text.isdigit() else None


def _unknown(text: str | None) -> str | None:
    return None if text is None or text.lower() in ("unknown", "empty", "") else text


def _entry(mc: int, path: Path) -> EdacDimm | None:
    """One ``dimmM``/``rankM`` directory, ``None`` when it reports no size."""
    size = _int(_read(path / "size"))
    if not size:
        return None
    return EdacDimm(mc, path.name, _read(path / "dimm_label") or "",
                    parse_location_text(_read(path / "dimm_location") or ""), size,
                    _unknown(_read(path / "dimm_mem_type")), _unknown(_read(path / "dimm_dev_type")),
                    _unknown(_read(path / "dimm_edac_mode")))


def join_ranks(ranks: list[EdacDimm]) -> list[EdacDimm]:
    """Ranks (``rank*/`` entries) joined into DIMMs: chip selects 2k and 2k+1 of a channel are DIMM k.

    Example:
        >>> r = [EdacDimm(0, f"rank{i}", "", {"csrow": cs, "channel": 3}, 16384, None, "x4", None)
        ...      for i, cs in ((3, 0), (11, 1))]
        >>> d = join_ranks(r)[0]
        >>> d.name, d.size_mb, d.ranks, d.location
        ('rank3+rank11', 32768, 2, {'channel': 3, 'slot': 0, 'csrow': 0})
    """
    groups: dict[tuple[int, int, int], list[EdacDimm]] = {}
    for rank in ranks:
        cs = rank.location.get("csrow", 0)
        groups.setdefault((rank.mc, rank.location.get("channel", 0), cs // 2), []).append(rank)
    out: list[EdacDimm] = []
    for (_mc, channel, slot), members in sorted(groups.items()):
        first = min(members, key=lambda r: r.location.get("csrow", 0))
        out.append(replace(first, name="+".join(r.name for r in members),
                           location={"channel": channel, "slot": slot, "csrow": first.location.get("csrow", 0)},
                           size_mb=sum(r.size_mb or 0 for r in members), ranks=len(members)))
    return out


def read_edac(root: Path = SYSFS_ROOT) -> tuple[list[EdacDimm], str]:
    """Every DIMM of every EDAC memory controller under ``root``, and a note on what was read.

    Args:
        root: the sysfs root.

    Returns:
        ``(dimms, note)``: the note names the source, or says why there is none.
    """
    base = root / "devices" / "system" / "edac" / "mc"
    controllers = sorted((int(m.group(1)), p) for p in base.glob("mc[0-9]*") if (m := re.fullmatch(r"mc(\d+)", p.name)))
    if not controllers:
        return [], "unknown: no devices/system/edac/mc/mc* (no EDAC driver loaded, or a VM)"
    dimms: list[EdacDimm] = []
    used_csrow = used_rank = False
    for mc, path in controllers:
        entries = sorted(path.glob("dimm[0-9]*"), key=lambda p: int(p.name[4:]))
        ranks = sorted(path.glob("rank[0-9]*"), key=lambda p: int(p.name[4:]))
        if entries or ranks:
            dimms.extend(e for e in (_entry(mc, p) for p in entries) if e is not None)
            joined = join_ranks([e for e in (_entry(mc, p) for p in ranks) if e is not None])
            used_rank = used_rank or bool(joined)
            dimms.extend(joined)
            continue
        for entry in sorted(path.glob("csrow[0-9]*"), key=lambda p: int(p.name[5:])):
            size = _int(_read(entry / "size_mb"))
            if not size:
                continue
            used_csrow = True
            label = _read(entry / "ch0_dimm_label") or ""
            dimms.append(EdacDimm(mc, entry.name, label, {"csrow": int(entry.name[5:])}, size,
                                  _unknown(_read(entry / "mem_type")), _unknown(_read(entry / "dev_type")),
                                  _unknown(_read(entry / "edac_mode"))))
    kind = ("csrow*/ (one entry per rank)" if used_csrow else
            "rank*/ (chip-select based driver: ranks joined into DIMMs by chip-select pair)" if used_rank else "dimm*/")
    return dimms, f"edac: devices/system/edac/mc/mc*/{kind}"
