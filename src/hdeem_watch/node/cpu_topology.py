"""CPU and NUMA topology from ``/sys/devices/system/cpu`` and ``/sys/devices/system/node``.

Read (Linux, ``Documentation/ABI/stable/sysfs-devices-system-cpu`` and ``.../sysfs-devices-node``):
``cpu/online`` (a CPU list such as ``0-47``), ``cpu/cpuN/topology/physical_package_id``,
``die_id`` (Linux >= 5.2), ``core_id``, and ``node/nodeN/cpulist``. The root is injected, so tests
run on checked-in fixture trees.

Example:
    >>> parse_cpu_list("0-3,8,10-11")
    [0, 1, 2, 3, 8, 10, 11]
"""

from __future__ import annotations

import re
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

from hdeem_watch.errors import InputError
from hdeem_watch.node.facts import Fact

SYSFS_ROOT = Path("/sys")


def parse_cpu_list(text: str) -> list[int]:
    """The CPUs of a kernel CPU list (``"0-11,24-35"``); empty text is no CPU.

    Raises:
        ValueError: text that is not a CPU list.
    """
    cpus: list[int] = []
    for part in text.strip().split(","):
        if not part:
            continue
        low, _, high = part.partition("-")
        cpus.extend(range(int(low), int(high or low) + 1))
    return cpus


def _read(path: Path) -> str | None:
    try:
        return path.read_text(encoding="utf-8").strip()
    except OSError:
        return None


@dataclass(frozen=True)
class CpuTopology:
    """Sockets, dies, cores, SMT and NUMA as sysfs shows them (each a :class:`Fact`).

    Attributes:
        sockets: number of sockets (packages).
        dies_per_socket: dies per package (``die_id``; 1 where the kernel has none).
        cores_per_socket: physical cores per socket.
        threads_per_core: hardware threads per core.
        numa_nodes_per_socket: NUMA nodes per socket (> 1: SNC on Intel, NPS on AMD).
        cpus_by_socket: logical CPUs of each socket (empty when unknown).
        numa_by_socket: NUMA node ids of each socket.
        cpus_by_numa: logical CPUs of each NUMA node (``node*/cpulist``; empty when unknown).
    """

    sockets: Fact[int]
    dies_per_socket: Fact[int]
    cores_per_socket: Fact[int]
    threads_per_core: Fact[int]
    numa_nodes_per_socket: Fact[int]
    cpus_by_socket: dict[int, list[int]] = field(default_factory=dict)
    numa_by_socket: dict[int, list[int]] = field(default_factory=dict)
    cpus_by_numa: dict[int, list[int]] = field(default_factory=dict)


def _uniform(counts: list[int], what: str, source: str) -> Fact[int]:
    if not counts:
        return Fact.unknown(f"no {what} in {source}")
    if len(set(counts)) > 1:
        return Fact(max(counts), f"{source} (uneven: {sorted(counts)}; the largest taken)")
    return Fact(counts[0], source)


def read_cpu_topology(root: Path = SYSFS_ROOT) -> CpuTopology:
    """Read the CPU and NUMA topology under ``root`` (``/sys`` on a real node).

    Args:
        root: the sysfs root (a fixture tree in tests).
    """
    cpu_dir = root / "devices" / "system" / "cpu"
    online_text = _read(cpu_dir / "online")
    if online_text is None:
        cpus = sorted(int(m.group(1)) for p in cpu_dir.glob("cpu[0-9]*")
                      if (m := re.fullmatch(r"cpu(\d+)", p.name)))
    else:
        cpus = parse_cpu_list(online_text)
    package: dict[int, int] = {}
    core: dict[int, tuple[int, int, int]] = {}
    dies: dict[int, set[int]] = defaultdict(set)
    has_die = False
    for cpu in cpus:
        topo = cpu_dir / f"cpu{cpu}" / "topology"
        pkg, core_id, die = (_read(topo / n) for n in ("physical_package_id", "core_id", "die_id"))
        if pkg is None or core_id is None:
            continue
        package[cpu] = _number(topo / "physical_package_id", pkg)
        has_die = has_die or die is not None
        die_id = _number(topo / "die_id", die) if die is not None else 0
        dies[package[cpu]].add(die_id)
        core[cpu] = (package[cpu], die_id, _number(topo / "core_id", core_id))
    source = "sysfs: devices/system/cpu/cpu*/topology"
    if not package:
        why = "no devices/system/cpu/cpu*/topology (not Linux, or sysfs not mounted)"
        unknown: Fact[int] = Fact.unknown(why)
        numa_fact, _by_socket, cpus_by_numa = _numa(root, {})
        return CpuTopology(unknown, unknown, unknown, unknown, numa_fact, cpus_by_numa=cpus_by_numa)
    by_socket: dict[int, list[int]] = defaultdict(list)
    for cpu, socket in sorted(package.items()):
        by_socket[socket].append(cpu)
    cores_by_socket = {s: len({core[c] for c in cs}) for s, cs in by_socket.items()}
    threads = [len(cs) // max(1, cores_by_socket[s]) for s, cs in by_socket.items()]
    die_fact = _uniform([len(d) for d in dies.values()], "dies", f"{source}/die_id") if has_die else \
        Fact(1, f"{source} (no die_id: kernel < 5.2; one die per package assumed)")
    numa_fact, numa_by_socket, cpus_by_numa = _numa(root, package)
    return CpuTopology(
        sockets=Fact(len(by_socket), f"{source}/physical_package_id"),
        dies_per_socket=die_fact,
        cores_per_socket=_uniform(list(cores_by_socket.values()), "cores", f"{source}/core_id"),
        threads_per_core=_uniform(threads, "threads", f"{source} (CPUs per core)"),
        numa_nodes_per_socket=numa_fact,
        cpus_by_socket=dict(by_socket),
        numa_by_socket=numa_by_socket,
        cpus_by_numa=cpus_by_numa,
    )


def _numa(root: Path, package: dict[int, int]) -> tuple[Fact[int], dict[int, list[int]], dict[int, list[int]]]:
    """NUMA nodes per socket from ``node/node*/cpulist`` and the CPUs' packages; the NUMA nodes of
    each socket; the CPUs of each NUMA node."""
    node_dir = root / "devices" / "system" / "node"
    source = "sysfs: devices/system/node/node*/cpulist"
    nodes = sorted(int(m.group(1)) for p in node_dir.glob("node[0-9]*") if (m := re.fullmatch(r"node(\d+)", p.name)))
    if not nodes:
        return Fact.unknown("no devices/system/node/node* (kernel without NUMA)"), {}, {}
    by_socket: dict[int, list[int]] = defaultdict(list)
    cpus_by_numa: dict[int, list[int]] = {}
    for node in nodes:
        text = _read(node_dir / f"node{node}" / "cpulist")
        cpus = parse_cpu_list(text) if text else []
        if cpus:
            cpus_by_numa[node] = cpus
        sockets = {package[c] for c in cpus if c in package}
        if len(sockets) == 1:
            by_socket[sockets.pop()].append(node)
    if not by_socket:
        if len(nodes) == 1:
            return Fact(1, source), {}, cpus_by_numa
        return Fact.unknown(f"{len(nodes)} NUMA nodes, none mapped to one socket (memory-only nodes?)"), {}, cpus_by_numa
    return _uniform([len(v) for v in by_socket.values()], "NUMA nodes", source), dict(by_socket), cpus_by_numa


def _number(path: Path, text: str) -> int:
    """A sysfs topology number (``core_id`` …).

    Raises:
        InputError: not a whole number, naming the file (a damaged capture, not a crash).
    """
    try:
        return int(text)
    except ValueError:
        raise InputError(f"{path}: {text.strip()!r} is not a number; expected the kernel's topology id") from None
