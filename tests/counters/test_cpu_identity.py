"""CPU generation from /proc/cpuinfo (model numbers of intel/perfmon's mapfile.csv)."""

from __future__ import annotations

from pathlib import Path

import pytest

from hdeem_watch.counters.cpu_identity import CpuIdentity, generation_of, parse_cpuinfo, read_cpuinfo
from hdeem_watch.errors import InputError

FIXTURES = Path(__file__).resolve().parent / "fixtures"
CPUINFO = FIXTURES / "cpuinfo"


@pytest.mark.parametrize(("name", "generation"), [
    ("haswell_ep", "haswell-ep"), ("ice_lake_sp", "ice-lake-sp"), ("cascade_lake_sp", "cascade-lake-sp"),
    ("sapphire_rapids", "sapphire-rapids"), ("genoa", "zen4"), ("vm_amd_epyc", "zen5")])
def test_fixture_hosts(name, generation):
    """Each fixture cpuinfo maps to its generation; the AMD VM's host CPU (family 26 model 2, Turin) to Zen 5."""
    assert generation_of(read_cpuinfo(CPUINFO / name)) == generation


@pytest.mark.parametrize(("model", "stepping", "generation"), [
    (0x3F, 2, "haswell-ep"), (0x4F, 1, "broadwell-ep"), (0x55, 4, "skylake-sp"), (0x55, 5, "cascade-lake-sp"),
    (0x55, 11, "cascade-lake-sp"), (0x6A, 6, "ice-lake-sp"), (0x6C, 1, "ice-lake-sp"), (0x8F, 8, "sapphire-rapids"),
    (0x56, 3, None), (0x3C, 3, None)])
def test_model_and_stepping_table(model, stepping, generation):
    """0x55 splits by stepping (0-4 Skylake-SP, 5+ Cascade Lake-SP); client parts and BDW-DE have no table."""
    assert generation_of(CpuIdentity("GenuineIntel", 6, model, stepping, "")) == generation


@pytest.mark.parametrize(("family", "model", "generation"), [
    (25, 0x01, None), (25, 0x21, None), (25, 0x50, None),        # Zen 3 (Milan, Vermeer, Cezanne): no UMC PMU
    (25, 0x11, "zen4"), (25, 0x61, "zen4"), (25, 0xA0, "zen4"),  # Genoa, Raphael, Siena/Bergamo
    (26, 0x02, "zen5"), (26, 0x11, "zen5"), (26, 0x44, "zen5"), (26, 0x30, None), (23, 0x31, None)])
def test_amd_families_follow_perfs_mapfile(family, model, generation):
    """perf's mapfile.csv: family 25 is Zen 4 except models 00-0F and 20-5F; family 26 models 00-2F, 40-4F,
    60-7F are Zen 5; Zen 2 (family 23) has no UMC PMU."""
    assert generation_of(CpuIdentity("AuthenticAMD", family, model, 1, "")) == generation


def test_first_processor_only_and_missing_stepping():
    """Only the first entry counts; a virtual CPU without ``stepping`` still parses."""
    ident = parse_cpuinfo("vendor_id: GenuineIntel\ncpu family: 6\nmodel: 63\n\nvendor_id: Other\nmodel: 1\n")
    assert (ident.vendor, ident.model, ident.stepping) == ("GenuineIntel", 63, -1)


def test_bad_cpuinfo_names_the_file(tmp_path):
    """A file without identity lines, or unreadable, is a one-line InputError naming it."""
    bad = tmp_path / "cpuinfo"
    bad.write_text("processor: 0\n")
    with pytest.raises(InputError, match=r"cpuinfo: no 'vendor_id'"):
        read_cpuinfo(bad)
    with pytest.raises(InputError, match="cannot read"):
        read_cpuinfo(tmp_path / "absent")
    with pytest.raises(InputError, match="model = 'x'"):
        parse_cpuinfo("vendor_id: GenuineIntel\ncpu family: 6\nmodel: x\n")
