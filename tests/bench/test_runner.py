"""Tests of the bench runner: pinning, first touch, memory and LLC checks, CPU order."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import pytest

from hdeem_watch.bench import system
from hdeem_watch.bench.runner import choose_cpus, run_one, validate
from hdeem_watch.bench.schedule import RunSpec
from hdeem_watch.errors import InputError

ALLOWED = sorted(os.sched_getaffinity(0))


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["thread", "process"])
def test_workers_are_pinned_to_distinct_allowed_cpus(backend: str) -> None:
    """Each worker runs pinned to exactly one allowed CPU, a different one per worker."""
    threads = min(2, len(ALLOWED))
    result = run_one(RunSpec("copy", threads, 8 * 4096, 2), backend=backend)
    assert len(result.cpus) == threads
    assert set(result.cpus) <= set(ALLOWED)
    assert len(set(result.cpus)) == threads
    assert result.worker_affinity == tuple((cpu,) for cpu in result.cpus)


def test_thread_affinity_seen_from_outside_while_running() -> None:
    """While the window is about to open, the kernel sees each worker thread's single-CPU mask."""
    seen: dict[str, set[int]] = {}

    def on_start(spec: RunSpec) -> dict[str, object]:
        for thread in threading.enumerate():
            if thread.name.startswith("bench-") and thread.native_id is not None:
                seen[thread.name] = os.sched_getaffinity(thread.native_id)
        return {"observed": len(seen)}

    threads = min(2, len(ALLOWED))
    result = run_one(RunSpec("read", threads, 8 * 4096, 1), on_start=on_start)
    assert result.announce["observed"] == threads
    assert sorted(seen) == [f"bench-{i}" for i in range(threads)]
    assert [seen[f"bench-{i}"] for i in range(threads)] == [{cpu} for cpu in result.cpus]
    assert os.sched_getaffinity(0) == set(ALLOWED)  # the main thread is not pinned


def test_restricted_cpu_set_is_respected() -> None:
    """With an allowed set of one CPU the worker uses that CPU; two threads are refused."""
    cpu = ALLOWED[-1]
    result = run_one(RunSpec("assign", 1, 8 * 1024, 1), allowed=[cpu])
    assert result.cpus == (cpu,) and result.worker_affinity == ((cpu,),)
    with pytest.raises(InputError, match="only 1 CPUs"):
        run_one(RunSpec("assign", 2, 8 * 1024, 1), allowed=[cpu])
    assert choose_cpus(3, [cpu], oversubscribe=True) == [cpu, cpu, cpu]


def test_memory_check_refuses_before_allocating() -> None:
    """Arrays larger than the available memory are an InputError naming --elements, not an OOM."""
    with pytest.raises(InputError) as info:
        run_one(RunSpec("add", 1, 10**9, 1), available_bytes=1 << 30)
    message = str(info.value)
    assert "--elements 1000000000" in message and "GiB" in message and "\n" not in message
    with pytest.raises(InputError):
        validate([RunSpec("read", 1, 1024, 1), RunSpec("add", 1, 10**15, 1)])
    # 3 arrays x 8 MB fit in 1 GiB: no error.
    system.check_memory(3 * 8 * 10**6, "x", available_bytes=1 << 30)


def _fake_sys(root: Path, layout: list[tuple[int, int, int]], llc: str = "32768K") -> Path:
    """A sysfs CPU tree: layout = [(cpu, package, core)], L1d/L2/L3 caches on each CPU."""
    for cpu, package, core in layout:
        topo = root / f"cpu{cpu}" / "topology"
        topo.mkdir(parents=True)
        (topo / "physical_package_id").write_text(f"{package}\n")
        (topo / "core_id").write_text(f"{core}\n")
        for index, (level, kind, size) in enumerate([(1, "Data", "32K"), (1, "Instruction", "32K"),
                                                      (2, "Unified", "1024K"), (3, "Unified", llc)]):
            d = root / f"cpu{cpu}" / "cache" / f"index{index}"
            d.mkdir(parents=True)
            (d / "level").write_text(f"{level}\n")
            (d / "type").write_text(f"{kind}\n")
            (d / "size").write_text(f"{size}\n")
    return root


def test_cpu_order_fills_socket0_cores_before_smt(tmp_path: Path) -> None:
    """Pinning order: socket 0's physical cores, then socket 1's, then the hyper-threads."""
    # 2 sockets x 2 cores x 2 SMT; Linux numbering: 0-3 first threads, 4-7 siblings.
    layout = [(0, 0, 0), (1, 0, 1), (2, 1, 0), (3, 1, 1), (4, 0, 0), (5, 0, 1), (6, 1, 0), (7, 1, 1)]
    root = _fake_sys(tmp_path / "cpu", layout)
    assert system.cpu_order(range(8), root) == [0, 1, 2, 3, 4, 5, 6, 7]
    assert system.cpu_order([7, 6, 5, 4, 3, 2, 1, 0], root) == [0, 1, 2, 3, 4, 5, 6, 7]
    # Interleaved numbering (siblings adjacent): cores first anyway.
    layout2 = [(0, 0, 0), (1, 0, 0), (2, 0, 1), (3, 0, 1)]
    root2 = _fake_sys(tmp_path / "cpu2", layout2)
    assert system.cpu_order(range(4), root2) == [0, 2, 1, 3]
    assert system.cpu_order([5, 9], tmp_path / "missing") == [5, 9]


def test_llc_size_and_warning(tmp_path: Path) -> None:
    """The LLC is the highest-level data cache, one per package; small arrays get a warning."""
    root = _fake_sys(tmp_path / "cpu", [(0, 0, 0), (1, 1, 0)], llc="30M")
    assert system.llc_bytes(root, 0) == 30 << 20
    assert system.llc_total_bytes([0, 1], root) == 60 << 20
    assert system.llc_total_bytes([0], root) == 30 << 20
    warning = system.llc_warning(100 << 20, [0, 1], root)
    assert warning is not None and "last-level cache" in warning
    assert system.llc_warning(240 << 20, [0, 1], root) is None
    assert system.llc_warning(1, [0], tmp_path / "none") is None


def _epyc_sys(root: Path) -> Path:
    """A sysfs CPU tree as Linux presents an AMD EPYC 7702 (Zen 2, 64 cores, SMT): one package, four
    cores per CCX, each CCX with its own 16 MiB L3. Shown here: CCX 0 (CPUs 0-3, siblings 64-67)
    and CCX 1 (CPUs 4-7, siblings 68-71). Per CPU, ``cache/indexN/`` holds ``level``, ``type``,
    ``size``, ``id`` and ``shared_cpu_list`` (the CPUs sharing that cache instance), the layout of
    the kernel's Documentation/ABI/testing/sysfs-devices-system-cpu; L1 and L2 are per core."""
    for ccx in (0, 1):
        for core in range(4 * ccx, 4 * ccx + 4):
            for cpu in (core, core + 64):
                topo = root / f"cpu{cpu}" / "topology"
                topo.mkdir(parents=True)
                (topo / "physical_package_id").write_text("0\n")
                (topo / "core_id").write_text(f"{core}\n")
                l3_cpus = f"{4 * ccx}-{4 * ccx + 3},{64 + 4 * ccx}-{64 + 4 * ccx + 3}"
                for index, (level, kind, size, cache_id, shared) in enumerate([
                        (1, "Data", "32K", core, f"{core},{core + 64}"),
                        (1, "Instruction", "32K", core, f"{core},{core + 64}"),
                        (2, "Unified", "512K", core, f"{core},{core + 64}"),
                        (3, "Unified", "16384K", ccx, l3_cpus)]):
                    d = root / f"cpu{cpu}" / "cache" / f"index{index}"
                    d.mkdir(parents=True)
                    for name, value in (("level", level), ("type", kind), ("size", size), ("id", cache_id),
                                        ("shared_cpu_list", shared)):
                        (d / name).write_text(f"{value}\n")
    return root


def test_llc_on_epyc_sums_every_l3_instance_of_a_package(tmp_path: Path) -> None:
    """On EPYC the L3 is per CCX, several per package: the LLC the workers can use is the sum over
    the distinct L3 instances their CPUs sit on (it used to be the largest L3 per package), so the
    "arrays too small" warning fires there too."""
    root = _epyc_sys(tmp_path / "cpu")
    assert system.llc_bytes(root, 5) == 16 << 20
    assert system.llc_total_bytes([0, 1, 64], root) == 16 << 20     # one CCX
    assert system.llc_total_bytes([0, 4], root) == 32 << 20         # two CCXs
    assert system.llc_total_bytes(range(8), root) == 32 << 20
    warning = system.llc_warning(100 << 20, [0, 4], root)           # 100 MiB < 4 x 32 MiB
    assert warning is not None and "(32.0 MiB)" in warning
    assert system.llc_warning(100 << 20, [0, 1], root) is None      # >= 4 x 16 MiB


def test_small_run_warns_about_llc() -> None:
    """A run whose arrays fit in the cache carries the LLC warning in its result."""
    llc = system.llc_total_bytes(ALLOWED)
    result = run_one(RunSpec("copy", 1, 8 * 1024, 1))
    if llc is None:
        assert result.warnings == ()
    else:
        assert any("last-level cache" in w for w in result.warnings)


def test_available_memory_respects_cgroup_limit(tmp_path: Path) -> None:
    """A cgroup v2 memory.max caps the available memory at max − current; 'max' means no cap."""
    (tmp_path / "memory.max").write_text(f"{1 << 30}\n")
    (tmp_path / "memory.current").write_text(f"{256 << 20}\n")
    assert system.available_memory_bytes(tmp_path) <= (1 << 30) - (256 << 20)
    (tmp_path / "memory.max").write_text("max\n")
    unlimited = system.available_memory_bytes(tmp_path)
    uncapped = system.available_memory_bytes(tmp_path / "no-cgroup")
    assert unlimited > 0 and abs(unlimited - uncapped) < 256 << 20


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["thread", "process"])
def test_a_run_sized_by_seconds_lasts_them_and_announces_its_pass_count(backend: str) -> None:
    """Issue 28: ``seconds`` replaces the repeat by the passes that fill it (from probe passes
    outside the window); the announced spec carries that count, and the window lasts about as long
    (at least half: a shared machine only slows a run down, the fastest probe pass is the guide)."""
    seen: list[RunSpec] = []
    result = run_one(RunSpec("triad", 2, 1 << 16, 1), backend=backend, seconds=0.3,
                     on_start=lambda spec: seen.append(spec) or {})
    assert result.spec.repeat > 10 and seen[0].repeat == result.spec.repeat
    assert 0.15 <= result.seconds < 5.0


def test_seconds_must_be_positive() -> None:
    """A non-positive or non-finite ``seconds`` is refused before any worker starts."""
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(InputError, match="--seconds"):
            run_one(RunSpec("copy", 1, 1 << 12, 1), seconds=bad)
