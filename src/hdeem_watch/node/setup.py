"""The node the daemon models: its description, the memspec for its DIMMs, its topology and sensors.

At start-up the daemon (:mod:`hdeem_watch.daemon.shell.service`) asks :func:`node_setup` what to model:

- the **description**: detected from this machine (:func:`detect_live_node`: sysfs, EDAC and, as
  root, ``dmidecode -t 17``), or the simulated node's (:func:`counted_node` of the sim's layout),
  or the ``[node]`` table alone (a replayed recording is not this machine); then the ``[node]``
  table's facts over it (:func:`~hdeem_watch.node.overrides.apply_overrides`, source ``config [node]``);
- the **memspec**: ``[node] memspec``, else the daemon's ``memspec`` setting, else the preset
  chosen from the DIMMs (:func:`~hdeem_watch.node.memspec_choice.choose_memspec`), else
  :data:`DEFAULT_MEMSPEC` — with the reason and the confidence, which the daemon logs;
- the **topology** of the run model (:func:`~hdeem_watch.node.topology.topology_from_node`), or
  ``None`` with the reason when the description lacks a count the model needs (the daemon then
  keeps its legacy default, the Taurus Haswell-EP blade);
- the **sensor map** (:func:`~hdeem_watch.node.sensors.sensor_map`, ``[node.sensors]`` over it).

Example:
    >>> sim = counted_node(2, 12, 4, source="sim: the simulated node")
    >>> setup = node_setup(sim, None, memspec_setting=None, default_memspec=(DEFAULT_MEMSPEC, "the sim's DIMMs"))
    >>> setup.memspec, setup.choice.confidence, setup.topology.dimms, setup.sensors["DDR_GH"]
    ('samsung-m393a1g43db0-cpb', 'default', 8, ['G', 'H'])
"""

from __future__ import annotations

import os
import shutil
import subprocess
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from hdeem_watch.dram.node import NodeTopology
from hdeem_watch.errors import InputError
from hdeem_watch.node.description import Dimm, NodeDescription, describe_node
from hdeem_watch.node.facts import Fact
from hdeem_watch.node.memspec_choice import MemspecChoice, choose_memspec
from hdeem_watch.node.overrides import NodeOverrides, apply_overrides
from hdeem_watch.node.sensors import sensor_map
from hdeem_watch.node.topology import topology_from_node

#: The memspec when neither the configuration nor the DIMMs name one (the Taurus blades' DIMMs).
DEFAULT_MEMSPEC = "samsung-m393a1g43db0-cpb"
#: Longest wait for ``dmidecode -t 17``.
DMIDECODE_TIMEOUT_S = 10.0


@dataclass(frozen=True)
class NodeSetup:
    """What the daemon models, and why.

    Attributes:
        description: the node (detected or configured facts, each with its source).
        memspec: the memspec of one DIMM (a preset name or a DRAMPower JSON file).
        choice: how the memspec was chosen (name, reason, confidence).
        topology: the run model's topology, ``None`` when the description cannot give one.
        topology_note: where the topology came from, or why there is none.
        sensors: sensor name → DIMM locators.
    """

    description: NodeDescription
    memspec: str
    choice: MemspecChoice
    topology: NodeTopology | None
    topology_note: str
    sensors: dict[str, list[str]] = field(default_factory=dict)

    def log_lines(self) -> list[str]:
        """What the daemon logs at start (one fact a line)."""
        lines = [f"node memspec {self.memspec} [{self.choice.confidence}]: {self.choice.reason}"]
        if self.topology is not None:
            topo = self.topology
            lines.append(f"node topology: {topo.sockets} socket(s) x {topo.cores_per_socket} cores, "
                         f"{topo.channels_per_socket} channel(s) x {topo.dimms_per_channel} DIMM(s) per socket, "
                         f"{topo.numa_nodes_per_socket} NUMA node(s) per socket ({self.topology_note})")
        else:
            lines.append(f"node topology: {self.topology_note}")
        return lines

    def to_json(self) -> dict[str, Any]:
        """The ``node.get`` reply: counts with their sources, DIMMs, memspec, topology, sensors, notes."""
        node = self.description
        facts = node.facts()
        topo = self.topology
        return {
            **{name: fact.value for name, fact in facts.items()},
            "facts": {name: fact.to_json() for name, fact in facts.items()},
            "dimms": [d.to_json(node.channel_letter(d)) for d in node.dimms],
            "memspec": {**self.choice.to_json(), "name": self.memspec},
            "topology": None if topo is None else {
                "sockets": topo.sockets, "cores_per_socket": topo.cores_per_socket,
                "channels_per_socket": topo.channels_per_socket, "dimms_per_channel": topo.dimms_per_channel,
                "numa_nodes_per_socket": topo.numa_nodes_per_socket, "threads_per_core": topo.threads_per_core,
                "ranks_per_dimm": topo.ranks_per_dimm, "dimms": topo.dimms},
            "topology_note": self.topology_note,
            "sensors": self.sensors,
            "notes": list(node.notes),
        }


def counted_node(sockets: int, cores_per_socket: int, channels_per_socket: int, *, dimms_per_channel: int = 1,
                 source: str) -> NodeDescription:
    """A node known only by its counts (e.g. the simulated node's layout), each fact tagged ``source``;
    its DIMMs are named by their node-wide channel letters (``A``, ``B``, ...; with a slot number
    after it when a channel has several), as the simulated node names them.

    Example:
        >>> counted_node(1, 8, 6, source="sim").channels_per_socket
        Fact(value=6, source='sim')
    """
    one = Fact(1, source)
    node = NodeDescription(
        sockets=Fact(int(sockets), source), dies_per_socket=one, cores_per_socket=Fact(int(cores_per_socket), source),
        threads_per_core=one, numa_nodes_per_socket=one, channels_per_socket=Fact(int(channels_per_socket), source),
        dimms_per_channel=Fact(int(dimms_per_channel), source))
    where = dict.fromkeys(("socket", "channel", "slot"), source)
    slots = [Dimm("", socket=s, channel=c, slot=k, sources=where) for s in range(int(sockets))
             for c in range(int(channels_per_socket)) for k in range(int(dimms_per_channel))]
    dimms = tuple(replace(d, locator=f"{node.channel_letter(d)}{'' if dimms_per_channel == 1 else d.slot}")
                  for d in slots)
    return replace(node, dimms=dimms)


def configured_only(why: str) -> NodeDescription:
    """A node of which nothing is detected (``why``): the ``[node]`` table describes it. Every
    count is unknown for that reason (not for a missing sysfs: nothing was looked up)."""
    import dataclasses

    described = describe_node(Path("/nonexistent"), None, why)
    unknown: Fact[int] = Fact.unknown(why)
    facts: dict[str, Any] = {f.name: unknown for f in dataclasses.fields(described)
                             if isinstance(getattr(described, f.name), Fact)}
    return replace(described, notes=(why,), **facts)


def dmidecode_text(*, run: Any = subprocess.run, which: Any = shutil.which,
                   euid: int | None = None) -> tuple[str | None, str]:
    """``dmidecode -t 17`` of this node, or ``None`` and why not (not installed, not root, failed).

    Args:
        run: ``subprocess.run`` (injected in tests).
        which: ``shutil.which``.
        euid: the effective user id (default ``os.geteuid()``).
    """
    tool = which("dmidecode")
    if tool is None:
        return None, "dmidecode is not installed (apt/dnf install dmidecode), or pass --dmidecode FILE"
    if (os.geteuid() if euid is None else euid) != 0:
        return None, "not root: dmidecode reads the SMBIOS table, readable by root only; pass --dmidecode FILE"
    try:
        done = run([tool, "-t", "17"], capture_output=True, text=True, timeout=DMIDECODE_TIMEOUT_S, check=False)
    except (OSError, subprocess.TimeoutExpired) as error:
        return None, f"running dmidecode failed: {error}"
    if done.returncode != 0 or "Memory Device" not in done.stdout:
        first = (done.stderr.strip().splitlines() or ["no Memory Device record (a VM without SMBIOS memory?)"])[0]
        return None, f"dmidecode -t 17: {first}"
    return done.stdout, "dmidecode -t 17 (run now)"


def saved_dmidecode(overrides: NodeOverrides | None) -> tuple[str | None, str] | None:
    """The ``[node] dmidecode`` print-out as ``(text, note)``, or ``None`` when the table names none.

    Raises:
        InputError: the file cannot be read (named with the key).
    """
    if overrides is None or not overrides.dmidecode:
        return None
    path = Path(overrides.dmidecode)
    try:
        return path.read_text(encoding="utf-8", errors="replace"), f"{path} ([node] dmidecode)"
    except OSError as error:
        raise InputError(f"[node].dmidecode = {str(path)!r}: cannot read ({error.strerror or error}); "
                         "expected a saved 'dmidecode -t 17' print-out") from None


def detect_live_node(sysfs_root: Path = Path("/sys"), *, cpuinfo: Path = Path("/proc/cpuinfo"),
                     dmidecode: tuple[str | None, str] | None = None) -> NodeDescription:
    """This node as sysfs, EDAC and (as root) ``dmidecode -t 17`` show it.

    Args:
        sysfs_root: the sysfs root.
        cpuinfo: ``/proc/cpuinfo`` (only to tell a virtual machine).
        dmidecode: ``(text, note)`` of a ``dmidecode -t 17`` print-out (default: :func:`dmidecode_text`).
    """
    text, note = dmidecode if dmidecode is not None else dmidecode_text()
    try:
        cpuinfo_text: str | None = cpuinfo.read_text(encoding="utf-8", errors="replace")
    except OSError:
        cpuinfo_text = None
    return describe_node(sysfs_root, text, note, cpuinfo_text=cpuinfo_text)


def choose(node: NodeDescription, overrides: NodeOverrides | None, memspec_setting: str | None, *,
           default: tuple[str, str] | None = None) -> MemspecChoice:
    """The memspec: ``[node] memspec``, the ``memspec`` setting, the DIMMs' preset, the default
    (``default``: ``(name, reason)`` instead of :data:`DEFAULT_MEMSPEC`, e.g. the simulated DIMMs')."""
    if overrides is not None and overrides.memspec:
        return MemspecChoice(overrides.memspec, "set in the [node] table (memspec)", "configured")
    if memspec_setting:
        return MemspecChoice(memspec_setting, "set by the memspec setting", "configured")
    choice = choose_memspec(node.dimms, cpu=node.cpu)
    unknown = not any(d.part_number or d.type or d.size_bytes for d in node.dimms)  # slots, nothing more
    if choice.name is None or (default is not None and unknown):
        name, reason = default or (DEFAULT_MEMSPEC, f"{choice.reason}; the default preset")
        return MemspecChoice(name, reason, "default")
    return choice


def node_setup(description: NodeDescription, overrides: NodeOverrides | None, *,
               memspec_setting: str | None, default_memspec: tuple[str, str] | None = None) -> NodeSetup:
    """What the daemon models for ``description`` with the ``[node]`` table ``overrides`` over it.

    Args:
        description: the detected (or simulated, or empty) description.
        overrides: the ``[node]`` table (``None``: none).
        memspec_setting: the daemon's ``memspec`` setting (``None``: choose from the DIMMs).
        default_memspec: ``(name, reason)`` when nothing chooses one (default :data:`DEFAULT_MEMSPEC`).
    """
    node = apply_overrides(description, overrides) if overrides is not None else description
    choice = choose(node, overrides, memspec_setting, default=default_memspec)
    topology: NodeTopology | None
    try:
        topology = topology_from_node(node)
        sources = {fact.source for fact in (node.sockets, node.cores_per_socket, node.channels_per_socket)}
        note = "from " + "; ".join(sorted(sources))
    except InputError as error:
        topology, note = None, f"{error}; the run model keeps its default node"
    sensors = sensor_map(node)
    if overrides is not None and overrides.sensors:
        sensors = {**sensors, **overrides.sensors}
    return NodeSetup(node, str(choice.name), choice, topology, note, sensors)
