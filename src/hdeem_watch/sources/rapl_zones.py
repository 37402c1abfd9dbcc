"""Powercap DRAM zones, each mapped to its socket (and die) through its package zone's name.

The zone directories do not say which socket they measure: the kernel numbers zones in
*registration* order and prints the number in hex (``intel-rapl:%x``, drivers/powercap/powercap_sys.c,
``powercap_register_zone``: ``idr_alloc`` then ``dev_set_name(..., "%s:%x", ...)``), so on a
multi-socket machine ``intel-rapl:0`` can be socket 1. The socket is in the parent (package) zone's
``name``: ``package-X``, or ``package-X-die-Y`` on multi-die parts (drivers/powercap/
intel_rapl_common.c, ``rapl_add_package``). ``/sys/class/powercap`` holds a symlink for every zone
(flat); the real directories nest subzones inside their package zone.

Zones are found by their ``name`` (``dram``), whatever driver registered them: the MSR driver
(``intel-rapl:``, Haswell-EP to Emerald Rapids), the MMIO one (``intel-rapl-mmio:``) and Granite
Rapids' TPMI driver (drivers/powercap/intel_rapl_tpmi.c maps ``TPMI_RAPL_DOMAIN_MEMORY`` to
``RAPL_DOMAIN_DRAM``, named ``dram``). Mainline registers the TPMI zones under the ``intel-rapl``
control type (commit 9eef7f9da928); Intel's TPMI driver (linux-intel-lts) under ``intel-rapl-tpmi``,
so ``intel-rapl-tpmi:<n>:<m>`` zones are read too.

Example:
    >>> channel_name(3, None), channel_name(1, 0)
    ('DRAM3', 'DRAM1_DIE0')
    >>> wrap_delta_uj(990, 40, 1000.0)
    50.0
    >>> round(wrap_modulus_uj(65712999613) - 65712999613, 3)   # Haswell-EP DRAM unit: 15.3 uJ
    15.3
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from hdeem_watch.sources.base import SourceUnavailable
from hdeem_watch.sources.cpu_vendor import no_dram_reason, read_cpuinfo

DEFAULT_ROOT = "/sys/class/powercap"
UDEV_RULE = "systemd/90-hdeem-watch-rapl.rules"
PERMISSION_FIX = ("energy_uj is root-only since the CVE-2020-8694 fix (Linux 5.10; backported to 4.4.243, "
                  "4.9.243, 4.14.206, 4.19.157, 5.4.77, 5.9.7); install " + UDEV_RULE + " (makes only the dram zones "
                  "readable by the group hdeem-watch), run the daemon as the privileged collector (root), or "
                  "use rapl_method = 'perf' (the power PMU; needs perf_event_paranoid <= 0 or CAP_PERFMON)")

_ZONE_ID = re.compile(r"^intel-rapl(?:-mmio|-tpmi)?:[0-9a-f]+(?::[0-9a-f]+)?$")
_PACKAGE = re.compile(r"^package-(\d+)(?:-die-(\d+))?$")


@dataclass(frozen=True)
class DramZone:
    """One DRAM zone.

    Attributes:
        channel: ``DRAM<socket>`` or ``DRAM<socket>_DIE<die>``.
        path: the zone's directory.
        socket, die: from the package zone's name (die None on single-die packages; socket -1 when
            the zone is not under a package zone).
        max_energy_range_uj: where ``energy_uj`` wraps.
    """

    channel: str
    path: Path
    socket: int
    die: int | None
    max_energy_range_uj: int


@dataclass(frozen=True)
class EnergyCounter:
    """One DRAM energy counter, of a powercap zone (:func:`~hdeem_watch.sources.rapl.powercap_counters`)
    or of the perf ``power`` PMU (:mod:`~hdeem_watch.sources.perf_energy`): ``read_raw()`` in counter
    units, ``joules_per_unit``, and where it wraps (``modulus``; None = a 64-bit count that does not
    wrap in practice)."""

    channel: str
    read_raw: Callable[[], int]
    joules_per_unit: float
    modulus: float | None


def read_text(path: Path) -> str:
    """A sysfs file's content (the default reader; tests inject others)."""
    return path.read_text()


def channel_name(socket: int, die: int | None) -> str:
    """``DRAM<socket>`` or ``DRAM<socket>_DIE<die>``."""
    return f"DRAM{socket}" if die is None else f"DRAM{socket}_DIE{die}"


def zone_package(zone: Path, read: Callable[[Path], str] = read_text) -> tuple[int, int | None] | None:
    """(socket, die) of a zone from its parent package zone's ``name``; None if the parent is not a
    package zone."""
    try:
        name = read(zone.resolve().parent / "name").strip()
    except OSError:
        return None
    m = _PACKAGE.match(name)
    if m is None:
        return None
    return int(m.group(1)), (int(m.group(2)) if m.group(2) is not None else None)


def find_dram_zones(root: str | Path = DEFAULT_ROOT, read: Callable[[Path], str] = read_text,
                    cpuinfo: str | Path = "/proc/cpuinfo") -> list[DramZone]:
    """DRAM zones under ``root`` (flat symlinks or nested directories), ordered by socket and die.

    Raises:
        SourceUnavailable: ``root`` is missing, holds no zone named ``dram`` (the reason says what
            this CPU offers, from ``cpuinfo``), or a zone cannot be read (permission, with the fix).
    """
    base = Path(root)
    if not base.is_dir():
        raise SourceUnavailable(f"rapl: {base} does not exist (no powercap: not Linux, or the intel_rapl "
                                "modules are not loaded)")
    found = [*base.glob("intel-rapl*"), *base.glob("intel-rapl*/intel-rapl*"),
             *base.glob("intel-rapl*/intel-rapl*/intel-rapl*")]
    candidates = sorted({p.resolve(): p for p in found if p.is_dir() and _ZONE_ID.match(p.name)}.items())
    zones: dict[tuple[int, int], DramZone] = {}
    for real, zone in candidates:
        try:
            if read(zone / "name").strip() != "dram":
                continue
            rng = int(read(zone / "max_energy_range_uj").strip())
        except PermissionError:
            raise SourceUnavailable(f"rapl: permission denied reading {zone}; {PERMISSION_FIX}") from None
        except (OSError, ValueError):
            continue
        placed = zone_package(real, read)
        if placed is None:   # not under a package zone: keep it, named after its directory
            key = (1 << 30, len(zones))
            zones[key] = DramZone("DRAM_" + real.name.upper().replace("-", "_").replace(":", "_"), zone, -1, None, rng)
            continue
        socket, die = placed
        zones.setdefault((socket, -1 if die is None else die), DramZone(channel_name(socket, die), zone, socket, die, rng))
    if not zones:
        raise SourceUnavailable(f"rapl: no DRAM zone (a powercap zone named 'dram') under {base}: "
                                f"{no_dram_reason(read_cpuinfo(cpuinfo))}")
    return [zones[k] for k in sorted(zones)]


#: The RAPL energy status registers are 32 bits wide (``ENERGY_STATUS_MASK`` 0xffffffff).
ENERGY_STATUS_STATES = 1 << 32


def wrap_modulus_uj(max_range_uj: int) -> float:
    """The period of a powercap ``energy_uj`` counter in µJ: 2³² counter units.

    The kernel (drivers/powercap/intel_rapl_common.c) reports ``energy_uj = raw · unit`` and
    ``max_energy_range_uj`` = ``ENERGY_STATUS_MASK · unit`` = (2³² − 1) · unit (``rapl_unit_xlate``,
    integer arithmetic), where ``raw`` is the 32-bit register. The register wraps from 2³² − 1 to 0,
    so ``energy_uj`` falls by 2³² · unit = ``max_energy_range_uj`` + one unit, not + 1 µJ (the
    difference, unit − 1 µJ, is 14.3 µJ per wrap with Haswell-EP's 15.3 µJ DRAM unit). The unit is
    recovered as ``max_energy_range_uj / (2³² − 1)`` (exact to 2.4e-10 µJ).
    """
    return max_range_uj * ENERGY_STATUS_STATES / (ENERGY_STATUS_STATES - 1)


def wrap_delta_uj(previous: int, current: int, modulus_uj: float) -> float:
    """Counter delta across at most one wrap: ``(current − previous) mod modulus`` (see
    :func:`wrap_modulus_uj`); within 1 µJ of the true energy (``energy_uj`` is truncated to µJ)."""
    return (current - previous) % modulus_uj
