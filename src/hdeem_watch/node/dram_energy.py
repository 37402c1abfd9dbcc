"""Where the node's DRAM energy comes from: a RAPL DRAM sensor per socket, or the counters and a model.

- Intel servers (Haswell-EP to Emerald Rapids through MSRs, Granite Rapids through TPMI) have a RAPL
  DRAM domain per package: the powercap zones named ``dram`` under ``class/powercap``
  (:func:`hdeem_watch.sources.rapl_zones.find_dram_zones`, which also reads Intel's TPMI driver's
  ``intel-rapl-tpmi:`` zones).
- AMD (Zen 1-5, EPYC included) has no DRAM energy sensor: its RAPL has package and core domains only
  (the kernel's ``intel_rapl_msr`` registers ``package-N`` zones with a ``core`` subzone on AMD). The
  DRAM energy of a job is then *modelled* from the ``amd_umc`` counters (activates, CASes, precharges
  and memory clocks per channel, :mod:`hdeem_watch.counters.event_tables`) with the currents of a
  memspec: the datasheet currents of the memspec given, or a calibrated memspec imported from a node
  that has DRAM sensors. :attr:`DramEnergy.model` says which applies.

Example:
    >>> from pathlib import Path
    >>> from hdeem_watch.node.cpu_model import CpuModel
    >>> genoa = CpuModel("AMD EPYC 9654 96-Core Processor", 25, 17, "dmidecode -t 4")
    >>> energy = detect_dram_energy(Path("/nonexistent"), genoa)
    >>> energy.sensor, energy.model
    (None, 'amd_umc counters x memspec currents')
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hdeem_watch.node.cpu_model import CpuModel, is_amd
from hdeem_watch.sources.base import SourceUnavailable
from hdeem_watch.sources.rapl_zones import find_dram_zones

#: What models the DRAM energy on a node without a DRAM sensor whose memory controller has counters.
UMC_MODEL = "amd_umc counters x memspec currents"
AMD_NO_SENSOR = ("AMD has no DRAM energy sensor (its RAPL has package and core domains only, EPYC too): "
                 "a job's DRAM energy is modelled from the amd_umc counters (ACT, CAS, PRE, MEMCLK per "
                 "channel; see hdeem-watch counters) with the memspec's currents")


@dataclass(frozen=True)
class DramEnergy:
    """The node's DRAM energy source.

    Attributes:
        sensor: ``"rapl"`` (RAPL DRAM zones found) or ``None`` (no DRAM sensor was found).
        zones: RAPL channel (``DRAM0``) → the zone's path below the sysfs root (``class/powercap/...``).
        model: what models the DRAM energy instead (``None``: nothing, or not needed).
        how: where this was read, or why there is no sensor (one line).
    """

    sensor: str | None
    how: str
    model: str | None = None
    zones: dict[str, str] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """``{"sensor", "zones", "model", "how"}``."""
        return {"sensor": self.sensor, "zones": dict(self.zones), "model": self.model, "how": self.how}


def detect_dram_energy(sysfs_root: Path, cpu: CpuModel | None) -> DramEnergy:
    """The RAPL DRAM zones under ``sysfs_root/class/powercap``, else why there are none (AMD: the model).

    Args:
        sysfs_root: the sysfs root (``/sys``; a fixture tree in tests).
        cpu: the node's CPU, to say why there is no sensor.
    """
    powercap = sysfs_root / "class" / "powercap"
    try:
        # the zones' own reason reads a cpuinfo; the node names its CPU itself, so none is given
        zones = find_dram_zones(powercap, cpuinfo=sysfs_root / "no-cpuinfo-here")
    except SourceUnavailable as error:
        if is_amd(cpu):
            return DramEnergy(None, AMD_NO_SENSOR, UMC_MODEL)
        if "permission" in error.reason:
            return DramEnergy(None, error.reason)
        where = f"no zone named 'dram' under {powercap}" if powercap.is_dir() else f"no {powercap} (no powercap)"
        return DramEnergy(None, f"no RAPL DRAM sensor found: {where}")
    placed = {z.channel: str(z.path.relative_to(sysfs_root)) if z.path.is_relative_to(sysfs_root) else str(z.path)
              for z in zones}
    kinds = sorted({Path(p).name.rsplit(":", 2)[0] for p in placed.values()})
    return DramEnergy("rapl", f"powercap: {len(zones)} zone(s) named 'dram' ({', '.join(kinds)}), "
                              "socket from the package zone's name", zones=placed)
