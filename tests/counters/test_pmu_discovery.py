"""IMC PMU discovery on fixture sysfs trees laid out like real hosts (see fixtures/README.md)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from hdeem_watch.counters.host_plan import free_running_note
from hdeem_watch.counters.pmu_discovery import discover_imc_pmus, list_pmus, parse_cpu_list
from hdeem_watch.errors import InputError


@pytest.fixture
def haswell_sysfs(pmu_trees: Path) -> Path:
    return pmu_trees / "sysfs_haswell_ep"


def test_haswell_ep_boxes_and_sockets(haswell_sysfs):
    """Haswell-EP with two home agents: boxes 0, 1, 4, 5, each counting both sockets via CPUs 0 and 12."""
    pmus = discover_imc_pmus(haswell_sysfs)
    assert [p.name for p in pmus] == ["uncore_imc_0", "uncore_imc_1", "uncore_imc_4", "uncore_imc_5"]
    assert [p.box for p in pmus] == [0, 1, 4, 5]
    assert all(p.cpus == (0, 12) and not p.free_running for p in pmus)
    assert len({p.pmu_type for p in pmus}) == 4
    assert pmus[0].formats["umask"].describe() == "config:8-15"


def test_ice_lake_sp_programmable_then_free_running(pmu_trees):
    """Ice Lake-SP: 12 channel boxes, then 4 per-controller free-running PMUs (not mistaken for channels)."""
    pmus = discover_imc_pmus(pmu_trees / "sysfs_ice_lake_sp")
    programmable = [p for p in pmus if not p.free_running]
    free = [p for p in pmus if p.free_running]
    assert [p.box for p in programmable] == list(range(12))
    assert [p.name for p in free] == [f"uncore_imc_free_running_{i}" for i in range(4)]
    assert pmus.index(free[0]) == 12


def test_vm_has_no_imc_pmu(pmu_trees):
    """This VM's PMU list has no uncore PMU: discovery returns nothing (not an error)."""
    vm_sysfs = pmu_trees / "sysfs_vm"
    assert discover_imc_pmus(vm_sysfs) == []
    assert list_pmus(vm_sysfs) == ["breakpoint", "msr", "software", "tracepoint", "uprobe"]
    assert discover_imc_pmus(vm_sysfs / "absent") == []


def test_malformed_pmu_directory_is_named(haswell_sysfs, tmp_path):
    """A bad ``type`` or ``cpumask``, or a missing ``format/``, is an InputError naming the file."""
    root = tmp_path / "sysfs"
    shutil.copytree(haswell_sysfs, root)
    pmu = root / "bus/event_source/devices/uncore_imc_4"
    (pmu / "cpumask").write_text("0,x\n")
    with pytest.raises(InputError, match="uncore_imc_4/cpumask"):
        discover_imc_pmus(root)
    (pmu / "cpumask").write_text("0,12\n")
    (pmu / "type").write_text("imc\n")
    with pytest.raises(InputError, match="uncore_imc_4/type"):
        discover_imc_pmus(root)
    (pmu / "type").write_text("12\n")
    shutil.rmtree(pmu / "format")
    with pytest.raises(InputError, match="uncore_imc_4/format"):
        discover_imc_pmus(root)


def test_cpu_lists():
    """Kernel CPU lists: single CPUs, ranges and both."""
    assert parse_cpu_list("0,12\n") == (0, 12)
    assert parse_cpu_list("0-2,8") == (0, 1, 2, 8)
    with pytest.raises(InputError):
        parse_cpu_list("")


@pytest.mark.parametrize(("tree", "expect"), [
    ("sysfs_ice_lake_sp", ("dclk", "ddrt_read", "ddrt_write", "read", "write")),
    ("sysfs_sapphire_rapids", ("dclk", "rpq_cycles", "wpq_cycles")),
])
def test_free_running_pmus_are_described_by_their_own_events(pmu_trees, tree, expect):
    """The kernel's free-running IMC events differ by generation (icx_/spr_uncore_imc_freerunning_events):
    Ice Lake-SP adds Optane ddrt_read/ddrt_write to dclk/read/write, Sapphire Rapids has dclk and the
    pending-queue cycles rpq_cycles/wpq_cycles, no bandwidth. The note names what the PMUs list."""
    free = [p for p in discover_imc_pmus(pmu_trees / tree) if p.free_running]
    assert len(free) == 4 and {p.events for p in free} == {expect}
    note = free_running_note(free)
    assert note is not None and f"({', '.join(expect)})" in note
    assert ("bandwidth" in note) is False and ("read/write" in note) is False
