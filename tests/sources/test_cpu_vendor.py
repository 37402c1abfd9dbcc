"""The 'no DRAM energy' message says what is true for the CPU at hand (fixtures: real /proc/cpuinfo
layouts of an Intel Xeon E5-2680 v3 (Taurus' Haswell-EP), an AMD EPYC 7763 and an Intel Core i7-1165G7)."""

from __future__ import annotations

from pathlib import Path

import pytest

from hdeem_watch.sources.base import SourceUnavailable
from hdeem_watch.sources.cpu_vendor import no_dram_reason, read_cpuinfo
from hdeem_watch.sources.rapl import RaplSource

CPUINFO = Path(__file__).resolve().parent / "fixtures" / "cpuinfo"


def test_identity_is_read_from_the_first_processor():
    """Vendor, family, model and name come from the first processor block."""
    info = read_cpuinfo(CPUINFO / "intel_xeon_e5_2680v3.txt")
    assert info is not None
    assert (info.vendor, info.family, info.model) == ("GenuineIntel", 6, 63) and info.server


@pytest.mark.parametrize(("fixture", "says", "never"), [
    ("amd_epyc_7763.txt", "this AMD CPU (AMD EPYC 7763 64-Core Processor) exposes no DRAM energy", "client"),
    ("intel_core_i7_1165g7.txt", "this Intel client CPU", "BIOS"),
    ("intel_xeon_e5_2680v3.txt", "normally has a DRAM domain: check that the BIOS", "client"),
])
def test_message_by_vendor_and_class(fixture, says, never):
    """EPYC is not called a client CPU; a Xeon without a DRAM zone points at the BIOS; a client CPU
    says client parts have none. Every message names what to use instead."""
    reason = no_dram_reason(read_cpuinfo(CPUINFO / fixture))
    assert says in reason and never not in reason
    assert "hdeem" in reason and "replay" in reason


def test_rapl_source_on_epyc_gives_the_amd_reason(powercap_trees):
    """The rapl source with no dram zone on an EPYC: unavailable, with the AMD message."""
    with pytest.raises(SourceUnavailable, match=r"AMD CPU .*no DRAM energy.*EPYC servers too"):
        RaplSource(root=powercap_trees / "powercap_laptop", cpuinfo=CPUINFO / "amd_epyc_7763.txt").open()


def test_unreadable_cpuinfo(tmp_path):
    """No /proc/cpuinfo: still a reason, still the alternatives."""
    assert read_cpuinfo(tmp_path / "none") is None
    assert "replay" in no_dram_reason(None)
