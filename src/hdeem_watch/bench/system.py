"""What the bench needs to know about the machine: CPU order, LLC size, free memory.

All readers take the sysfs root and the CPU set as arguments so they can be tested against fixture
trees; the defaults read the live system. Which CPUs may be used is the SLURM adapter's business
(:func:`hdeem_watch.slurm.allowed_cpus`: the affinity mask that ``srun``, ``taskset`` and cpusets
restrict); here they are ordered (sysfs topology, psutil core count).

Example:
    >>> order = cpu_order({0, 1})
    >>> sorted(order) == [0, 1]
    True
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import psutil

from hdeem_watch.errors import InputError

SYS_CPU = Path("/sys/devices/system/cpu")
CGROUP_ROOT = Path("/sys/fs/cgroup")
#: Keep this fraction of the available memory free when checking an allocation.
MEMORY_HEADROOM = 0.10
#: Arrays smaller than this multiple of the LLC get a warning (caches would serve part of the traffic).
LLC_FACTOR = 4


def _read_int(path: Path) -> int | None:
    try:
        return int(path.read_text().strip())
    except (OSError, ValueError):
        return None


def cpu_order(cpus: Iterable[int], sys_cpu: Path = SYS_CPU) -> list[int]:
    """Order CPUs for pinning: socket 0 first, one CPU per physical core, then SMT siblings.

    Threads fill the first socket before the second (as on the seed paper's Haswell nodes) and use
    hyper-threads only when every allowed physical core has a worker. Unknown topology keeps the
    numeric order.

    Args:
        cpus: the allowed CPU numbers.
        sys_cpu: sysfs CPU directory (``/sys/devices/system/cpu`` or a fixture tree).
    """
    keyed = []
    seen_cores: dict[tuple[int, int], int] = {}
    for cpu in sorted(set(cpus)):
        topo = sys_cpu / f"cpu{cpu}" / "topology"
        package = _read_int(topo / "physical_package_id")
        core = _read_int(topo / "core_id")
        package = 0 if package is None else package
        core = cpu if core is None else core
        smt_rank = seen_cores.get((package, core), 0)
        seen_cores[(package, core)] = smt_rank + 1
        keyed.append(((smt_rank, package, core, cpu), cpu))
    return [cpu for _, cpu in sorted(keyed)]


def physical_cores() -> int | None:
    """Return psutil's count of physical cores (None if unknown)."""
    return psutil.cpu_count(logical=False)


def _parse_size(text: str) -> int | None:
    text = text.strip().upper()
    factor = {"K": 1 << 10, "M": 1 << 20, "G": 1 << 30}.get(text[-1:], 1)
    digits = text[:-1] if text[-1:] in "KMG" else text
    try:
        return int(digits) * factor
    except ValueError:
        return None


def _llc_index(sys_cpu: Path, cpu: int) -> tuple[Path, int] | None:
    """The sysfs directory and size (bytes) of the highest-level data cache ``cpu`` sees."""
    best: tuple[int, Path, int] | None = None
    cache_dir = sys_cpu / f"cpu{cpu}" / "cache"
    if not cache_dir.is_dir():
        return None
    for index in sorted(cache_dir.glob("index*")):
        level = _read_int(index / "level")
        try:
            kind = (index / "type").read_text().strip()
            size = _parse_size((index / "size").read_text())
        except OSError:
            continue
        if level is None or size is None or kind == "Instruction":
            continue
        if best is None or level > best[0]:
            best = (level, index, size)
    return None if best is None else (best[1], best[2])


def llc_bytes(sys_cpu: Path = SYS_CPU, cpu: int = 0) -> int | None:
    """Return the size of the last-level cache seen by ``cpu`` in bytes (None if unknown)."""
    found = _llc_index(sys_cpu, cpu)
    return None if found is None else found[1]


def _llc_domain(index: Path, sys_cpu: Path, cpu: int) -> tuple[str, str]:
    """Which cache instance ``index`` is: the CPUs sharing it (``shared_cpu_list``), else the
    kernel's cache ``id``, else (old kernels) the CPU's package."""
    for name in ("shared_cpu_list", "id"):
        try:
            return name, (index / name).read_text().strip()
        except OSError:
            continue
    package = _read_int(sys_cpu / f"cpu{cpu}" / "topology" / "physical_package_id") or 0
    return "package", str(package)


def llc_total_bytes(cpus: Iterable[int], sys_cpu: Path = SYS_CPU) -> int | None:
    """Return the LLC capacity the given CPUs can use: the sum over every distinct LLC instance.

    An instance is the set of CPUs that share it, as sysfs lists it: one per package on Intel
    Xeons, one per CCX (Zen 2) or CCD (Zen 3/4) on AMD EPYC, so that a package holds several.
    """
    domains: dict[tuple[str, str], int] = {}
    for cpu in cpus:
        found = _llc_index(sys_cpu, cpu)
        if found is None:
            continue
        index, size = found
        domains[_llc_domain(index, sys_cpu, cpu)] = size
    return sum(domains.values()) if domains else None


def available_memory_bytes(cgroup_root: Path = CGROUP_ROOT) -> int:
    """Return the memory available for new allocations: psutil's figure, capped by a cgroup v2 limit."""
    available = int(psutil.virtual_memory().available)
    limit = cgroup_root / "memory.max"
    current = cgroup_root / "memory.current"
    try:
        text = limit.read_text().strip()
        if text != "max":
            used = _read_int(current) or 0
            available = min(available, max(0, int(text) - used))
    except (OSError, ValueError):
        pass
    return available


def check_memory(needed_bytes: int, what: str, available_bytes: int | None = None) -> None:
    """Raise :class:`InputError` if ``needed_bytes`` does not fit in the available memory.

    Args:
        needed_bytes: bytes about to be allocated.
        what: the parameter responsible, for the message (e.g. ``"--elements 1e12 (copy)"``).
        available_bytes: override of :func:`available_memory_bytes` (tests).
    """
    available = available_memory_bytes() if available_bytes is None else int(available_bytes)
    usable = int(available * (1.0 - MEMORY_HEADROOM))
    if needed_bytes > usable:
        raise InputError(
            f"{what}: the arrays need {needed_bytes / 2**30:.2f} GiB but only "
            f"{available / 2**30:.2f} GiB of memory are available; expected at most "
            f"{usable / 2**30:.2f} GiB (fewer --elements)")


def llc_warning(array_bytes: int, cpus: Iterable[int], sys_cpu: Path = SYS_CPU) -> str | None:
    """Return a warning if the arrays are not much larger than the LLC (else None)."""
    llc = llc_total_bytes(list(cpus), sys_cpu)
    if llc is None or array_bytes >= LLC_FACTOR * llc:
        return None
    return (f"arrays of {array_bytes / 2**20:.1f} MiB are not much larger than the last-level cache "
            f"({llc / 2**20:.1f} MiB): part of the traffic stays in the cache; use at least "
            f"{LLC_FACTOR}x the LLC for DRAM measurements")
