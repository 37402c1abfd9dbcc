"""Granite Rapids: RAPL DRAM through TPMI zones (issue 30).

drivers/powercap/intel_rapl_tpmi.c maps ``TPMI_RAPL_DOMAIN_MEMORY`` to ``RAPL_DOMAIN_DRAM`` (a zone named
``dram``); Intel's TPMI driver registers the zones under the control type ``intel-rapl-tpmi``, mainline
under ``intel-rapl``. The trees are built by powercap_trees.py (cited there).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from hdeem_watch.sources.base import SourceUnavailable
from hdeem_watch.sources.rapl import RaplSource
from hdeem_watch.sources.rapl_zones import find_dram_zones

CPUINFO = Path(__file__).resolve().parent / "fixtures" / "cpuinfo"


def copy(trees: Path, tmp_path: Path, name: str) -> Path:
    shutil.copytree(trees / name, tmp_path / name, symlinks=True)
    return tmp_path / name


@pytest.mark.parametrize("name", ["powercap_gnr_tpmi", "powercap_gnr_mainline"])
def test_gnr_dram_zones_found_by_name(powercap_trees: Path, name: str) -> None:
    """Both spellings of the TPMI control type give one DRAM channel per package, psys skipped."""
    zones = find_dram_zones(powercap_trees / name / "class" / "powercap", cpuinfo=CPUINFO / "intel_xeon_6980p.txt")
    assert [(z.channel, z.socket, z.die) for z in zones] == [("DRAM0", 0, None), ("DRAM1", 1, None)]
    prefix = "intel-rapl-tpmi" if name.endswith("tpmi") else "intel-rapl"
    assert [z.path.name for z in zones] == [f"{prefix}:0:0", f"{prefix}:{2 if prefix.endswith('tpmi') else 1}:0"]


def test_gnr_tpmi_zones_are_read(powercap_trees: Path, tmp_path: Path, fake_clock) -> None:
    """The TPMI DRAM zones publish ΔE/Δt per socket like the MSR ones."""
    tree = copy(powercap_trees, tmp_path, "powercap_gnr_tpmi")
    clock = fake_clock(1_000_000_000)
    src = RaplSource(root=tree / "class" / "powercap", clock=clock, cpuinfo=CPUINFO / "intel_xeon_6980p.txt")
    src.open()
    devices = tree / "devices" / "virtual" / "powercap" / "intel-rapl-tpmi"
    for zone, delta in (("intel-rapl-tpmi:0/intel-rapl-tpmi:0:0", 7_000_000),
                        ("intel-rapl-tpmi:2/intel-rapl-tpmi:2:0", 3_000_000)):
        path = devices / zone / "energy_uj"
        path.write_text(f"{int(path.read_text()) + delta}\n")
    clock.t += 1_000_000_000
    batch = src.poll()
    got = {ch: float(p[0]) for ch, (_, p) in batch.samples.items() if len(p)}
    assert got == {"DRAM0": pytest.approx(7.0), "DRAM1": pytest.approx(3.0)}


def test_gnr_without_memory_domain_says_so(powercap_trees: Path) -> None:
    """A TPMI tree with no dram zone: the message names the TPMI driver for this Intel server CPU."""
    with pytest.raises(SourceUnavailable) as caught:
        find_dram_zones(powercap_trees / "powercap_gnr_tpmi_nodram" / "class" / "powercap",
                        cpuinfo=CPUINFO / "intel_xeon_6980p.txt")
    assert "Xeon(R) 6980P" in caught.value.reason and "intel_rapl_tpmi" in caught.value.reason
