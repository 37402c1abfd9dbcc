"""``NodeDescription``: sockets, cores, NUMA, memory channels and DIMMs of one node, with sources.

:func:`describe_node` joins the sysfs CPU/NUMA topology (:mod:`.cpu_topology`), the EDAC DIMMs
(:mod:`.edac`) and ``dmidecode -t 17`` (:mod:`.dmidecode`); every fact carries where it came from,
and what could not be detected is ``None`` with the reason. Channels are numbered per socket
(0, 1, ...) and lettered across the node (socket 0: A, B, ...; socket 1 continues), the way HDEEM
names its DIMM-pair sensors.

Example:
    >>> from pathlib import Path
    >>> node = describe_node(Path("/nonexistent"), None, "dmidecode: not given")
    >>> node.sockets.value is None, node.dimms
    (True, ())
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from hdeem_watch.node.bank_nodes import bank_node_rule
from hdeem_watch.node.cpu_model import CpuModel, cpu_from_cpuinfo, cpu_from_dmidecode, memory_controller
from hdeem_watch.node.cpu_topology import CpuTopology, read_cpu_topology
from hdeem_watch.node.dmidecode import MemoryDevice, parse_dmidecode
from hdeem_watch.node.dram_energy import DramEnergy, detect_dram_energy
from hdeem_watch.node.edac import EdacDimm, read_edac
from hdeem_watch.node.facts import Fact
from hdeem_watch.node.locators import SlotGuess, parse_location


@dataclass(frozen=True)
class Dimm:
    """One installed DIMM.

    Attributes:
        locator: the slot name (dmidecode ``Locator``, else the EDAC label).
        socket: socket (0-based), ``None`` unknown.
        channel: memory channel within the socket (0-based), ``None`` unknown.
        slot: slot within the channel (0-based).
        size_bytes: module size.
        type: memory type (``DDR4``).
        type_detail: e.g. ``Synchronous Registered (Buffered)``.
        speed_mts: rated speed (MT/s).
        configured_mts: configured speed (MT/s).
        ranks: ranks.
        data_width: data bits of the module (64; 72 with ECC is ``total_width``).
        total_width: data + ECC bits.
        device_width: DRAM device width (4, 8, 16).
        manufacturer: module manufacturer.
        part_number: module part number.
        sources: field name → where its value came from.
    """

    locator: str
    socket: int | None = None
    channel: int | None = None
    slot: int | None = None
    size_bytes: int | None = None
    type: str | None = None
    type_detail: str | None = None
    speed_mts: int | None = None
    configured_mts: int | None = None
    ranks: int | None = None
    data_width: int | None = None
    total_width: int | None = None
    device_width: int | None = None
    manufacturer: str | None = None
    part_number: str | None = None
    sources: dict[str, str] = field(default_factory=dict, compare=False)

    def to_json(self, channel_letter: str | None = None) -> dict[str, Any]:
        """The DIMM as a JSON object (``channel_letter``: its node-wide channel letter)."""
        return {"locator": self.locator, "socket": self.socket, "channel": self.channel,
                "channel_letter": channel_letter, "slot": self.slot, "size_bytes": self.size_bytes,
                "type": self.type, "type_detail": self.type_detail, "speed_mts": self.speed_mts,
                "configured_mts": self.configured_mts, "ranks": self.ranks, "data_width": self.data_width,
                "total_width": self.total_width, "device_width": self.device_width,
                "manufacturer": self.manufacturer, "part_number": self.part_number, "sources": dict(self.sources)}


@dataclass(frozen=True)
class NodeDescription:
    """What the node is, each fact with its source.

    Attributes:
        sockets, dies_per_socket, cores_per_socket, threads_per_core, numa_nodes_per_socket,
        channels_per_socket, dimms_per_channel: counts (:class:`Fact`).
        dimms: the installed DIMMs.
        cpus_by_socket: logical CPUs of each socket.
        notes: what could not be detected, and why (one line each).
        cpus_by_numa: logical CPUs of each NUMA node (sysfs ``node*/cpulist``).
        channel_rule: which rule placed the DIMMs in channels when a bank locator's ``NodeN`` had to
            be read (socket or memory controller), and what corroborates it; ``None`` otherwise.
        cpu: the CPU model (``/proc/cpuinfo`` or dmidecode type 4), ``None`` unknown.
        dram_energy: the DRAM energy source (RAPL DRAM zones, or none and what models it instead).
    """

    sockets: Fact[int]
    dies_per_socket: Fact[int]
    cores_per_socket: Fact[int]
    threads_per_core: Fact[int]
    numa_nodes_per_socket: Fact[int]
    channels_per_socket: Fact[int]
    dimms_per_channel: Fact[int]
    dimms: tuple[Dimm, ...] = ()
    cpus_by_socket: dict[int, list[int]] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    cpus_by_numa: dict[int, list[int]] = field(default_factory=dict)
    channel_rule: str | None = None
    cpu: CpuModel | None = None
    dram_energy: DramEnergy | None = None

    def channel_letter(self, dimm: Dimm) -> str | None:
        """The node-wide channel letter of ``dimm`` (socket 0: A, B, ...; socket 1 continues)."""
        per_socket = self.channels_per_socket.value
        if dimm.socket is None or dimm.channel is None or per_socket is None:
            return None
        index = dimm.socket * per_socket + dimm.channel
        return chr(ord("A") + index) if index < 26 else f"CH{index}"

    def facts(self) -> dict[str, Fact[int]]:
        """The counts by name."""
        return {"sockets": self.sockets, "dies_per_socket": self.dies_per_socket,
                "cores_per_socket": self.cores_per_socket, "threads_per_core": self.threads_per_core,
                "numa_nodes_per_socket": self.numa_nodes_per_socket,
                "channels_per_socket": self.channels_per_socket, "dimms_per_channel": self.dimms_per_channel}

    def with_facts(self, **facts: Fact[int]) -> NodeDescription:
        """A copy with some counts replaced (e.g. by the ``[node]`` configuration)."""
        return replace(self, **facts)  # type: ignore[arg-type]


def _dimms_from_dmidecode(devices: list[MemoryDevice]) -> tuple[list[tuple[Dimm, SlotGuess]], list[SlotGuess]]:
    """Installed DIMMs with their slot guesses, and the guesses of every slot (empty ones too)."""
    src = "dmidecode -t 17"
    installed: list[tuple[Dimm, SlotGuess]] = []
    every: list[SlotGuess] = []
    names = [d.locator for d in devices if d.installed]
    unique = len(set(names)) == len(names)
    for dev in devices:
        guess = parse_location(dev.locator, dev.bank_locator)
        every.append(guess)
        if not dev.installed:
            continue
        values = {"size_bytes": dev.size_bytes, "type": dev.type, "type_detail": dev.type_detail,
                  "speed_mts": dev.speed_mts, "configured_mts": dev.configured_mts, "ranks": dev.ranks,
                  "data_width": dev.data_width, "total_width": dev.total_width,
                  "manufacturer": dev.manufacturer, "part_number": dev.part_number}
        sources = {k: src for k, v in values.items() if v is not None}
        # boards that name slots per channel ("DIMM 0" in "P0 CHANNEL A") need the bank locator too
        locator = dev.locator if unique or not dev.bank_locator else f"{dev.bank_locator} {dev.locator}"
        installed.append((Dimm(locator=locator or dev.handle, sources=sources, **values), guess))  # type: ignore[arg-type]
    return installed, every


def _dimms_from_edac(edac: list[EdacDimm]) -> list[tuple[Dimm, SlotGuess]]:
    out: list[tuple[Dimm, SlotGuess]] = []
    for entry in edac:
        guess = parse_location(entry.label, None)
        if guess.socket is None and "channel" in entry.location:
            guess = SlotGuess(None, entry.mc, entry.location["channel"], None,
                              entry.location.get("slot", entry.location.get("dimm")), "EDAC dimm_location")
        width = int(entry.dev_type[1:]) if entry.dev_type and entry.dev_type[1:].isdigit() else None
        mem_type = entry.mem_type.split("-")[-1] if entry.mem_type else None
        values = {"size_bytes": None if entry.size_mb is None else entry.size_mb << 20, "type": mem_type,
                  "type_detail": entry.mem_type, "device_width": width, "ranks": entry.ranks}
        src = f"edac: mc{entry.mc}/{entry.name}"
        sources = {k: src for k, v in values.items() if v is not None}
        out.append((Dimm(locator=entry.label or f"mc{entry.mc}/{entry.name}", sources=sources, **values), guess))  # type: ignore[arg-type]
    return out


def _place(dimms: list[tuple[Dimm, SlotGuess]], every: list[SlotGuess], sockets: int | None,
           how_channels: str) -> tuple[list[Dimm], Fact[int], list[str]]:
    """Socket and per-socket channel of each DIMM, and the channels per socket."""
    notes: list[str] = []
    guesses = [g for _, g in dimms]
    shift = 1 if any(g.socket is not None and g.socket < 0 for g in every + guesses) else 0

    def key(g: SlotGuess) -> tuple[int, int, str] | None:
        if g.channel is not None:
            return (g.controller or 0, g.channel, "")
        if g.letter is not None:
            return (0, 0, g.letter)
        return None

    by_socket: dict[int, set[tuple[int, int, str]]] = defaultdict(set)
    unsocketed: set[tuple[int, int, str]] = set()
    for g in every or guesses:
        k = key(g)
        if k is None:
            continue
        if g.socket is None:
            unsocketed.add(k)
        else:
            by_socket[g.socket + shift].add(k)
    letter_socket: dict[tuple[int, int, str], tuple[int, int]] = {}
    if unsocketed:
        notes.append("slot names without a socket (e.g. 'A1') are board-specific (on some servers the letter is "
                     "the CPU, not the channel): check channels_per_socket and set it in the [node] table if wrong")
    if unsocketed and not by_socket and sockets:
        ordered = sorted(unsocketed)
        block = len(ordered) // sockets if len(ordered) % sockets == 0 else 0
        if block:
            letter_socket = {k: (i // block, i % block) for i, k in enumerate(ordered)}
            notes.append(f"DIMM sockets guessed: {len(ordered)} channel names split evenly over {sockets} sockets")
    index = {s: {k: i for i, k in enumerate(sorted(keys))} for s, keys in by_socket.items()}
    placed: list[Dimm] = []
    for dimm, g in dimms:
        k = key(g)
        socket = None if g.socket is None else g.socket + shift
        channel = index.get(socket, {}).get(k) if socket is not None and k is not None else None
        how = g.how
        if socket is None and k in letter_socket:
            socket, channel = letter_socket[k]
            how = f"{g.how}; socket guessed"
        sources = dict(dimm.sources)
        for name, value in (("socket", socket), ("channel", channel), ("slot", g.slot)):
            sources[name] = how if value is not None else f"unknown: {g.how}"
        placed.append(replace(dimm, socket=socket, channel=channel, slot=g.slot, sources=sources))
    counts = [len(v) for v in index.values()] or ([len(letter_socket) // sockets] if letter_socket and sockets else [])
    if not counts:
        return placed, Fact.unknown("no DIMM location could be read"), notes
    if len(set(counts)) > 1:
        return placed, Fact(max(counts), f"{how_channels} (uneven per socket: {counts})"), notes
    return placed, Fact(counts[0], how_channels), notes


def _dimms_per_channel(dimms: list[Dimm]) -> Fact[int]:
    per: dict[tuple[int, int], int] = defaultdict(int)
    for d in dimms:
        if d.socket is not None and d.channel is not None:
            per[(d.socket, d.channel)] += 1
    if not per:
        return Fact.unknown("no DIMM with a known socket and channel")
    counts = sorted(set(per.values()))
    if len(counts) > 1:
        return Fact(max(counts), f"installed DIMMs per channel (uneven: {counts})")
    return Fact(counts[0], "installed DIMMs per populated channel")


def _enrich_from_edac(dimms: list[Dimm], edac: list[EdacDimm]) -> list[Dimm]:
    """Device width from EDAC when every EDAC DIMM reports the same one (dmidecode has none)."""
    widths = {e.dev_type for e in edac if e.dev_type}
    if len(widths) != 1:
        return dimms
    width_text = widths.pop()
    if not width_text[1:].isdigit():
        return dimms
    width = int(width_text[1:])
    return [d if d.device_width is not None else
            replace(d, device_width=width, sources={**d.sources, "device_width": "edac: dimm_dev_type (all DIMMs)"})
            for d in dimms]


#: ``/sys/class/dmi/id/sys_vendor`` values of hypervisors (readable without root).
VM_VENDORS = ("QEMU", "KVM", "VMware", "innotek", "Xen", "Microsoft Corporation", "Amazon EC2", "Google",
              "OpenStack", "Red Hat")


def virtual_machine_hint(sysfs_root: Path, cpuinfo_text: str | None) -> str | None:
    """Why this looks like a virtual machine (``None``: it does not), for the notes."""
    try:
        vendor = (sysfs_root / "class" / "dmi" / "id" / "sys_vendor").read_text(encoding="utf-8").strip()
    except OSError:
        vendor = ""
    if any(vendor.startswith(v) for v in VM_VENDORS):
        why = f"sys_vendor {vendor!r}"
    elif cpuinfo_text is not None and any(line.startswith("flags") and " hypervisor" in line
                                          for line in cpuinfo_text.splitlines()):
        why = "the CPU flag 'hypervisor'"
    else:
        return None
    return (f"a virtual machine ({why}): a guest sees neither the memory controllers (EDAC) nor, usually, "
            f"the DIMMs (SMBIOS); set them in the [node] table")


def describe_node(sysfs_root: Path, dmidecode_text: str | None, dmidecode_note: str, *,
                  cpuinfo_text: str | None = None) -> NodeDescription:
    """Detect the node under ``sysfs_root`` (``/sys``) and from a ``dmidecode -t 17`` print-out.

    Args:
        sysfs_root: the sysfs root (a fixture tree in tests).
        dmidecode_text: dmidecode's output, ``None`` when it could not be read.
        dmidecode_note: where the text came from, or why there is none (shown in the notes).
        cpuinfo_text: ``/proc/cpuinfo`` (only to say whether this is a virtual machine).
    """
    cpu: CpuTopology = read_cpu_topology(sysfs_root)
    edac, edac_note = read_edac(sysfs_root)
    notes: list[str] = []
    vm = virtual_machine_hint(sysfs_root, cpuinfo_text)
    if vm is not None:
        notes.append(vm)
    devices = parse_dmidecode(dmidecode_text) if dmidecode_text else []
    if dmidecode_text is None:
        notes.append(f"dmidecode: {dmidecode_note}")
    elif not devices:
        notes.append(f"dmidecode: no 'Memory Device' (DMI type 17) record in {dmidecode_note}")
    if not edac:
        notes.append(edac_note)
    installed, every = _dimms_from_dmidecode(devices)
    cpu_model = cpu_from_cpuinfo(cpuinfo_text) or cpu_from_dmidecode(dmidecode_text)
    rule = bank_node_rule(every, memory_controller(cpu_model))
    if rule is not None:
        installed = [(dimm, rule.place(g)) for dimm, g in installed]
        every = [rule.place(g) for g in every]
    if installed:
        how = "dmidecode: distinct channels of the slots listed (populated or not)"
        if rule is not None:
            how += f"; {rule.text}"
        placed, channels, more = _place(installed, every, cpu.sockets.value, how)
        dimms = _enrich_from_edac(placed, edac)
    elif edac:
        how = "edac: distinct channels of the populated DIMMs (empty channels are not listed)"
        placed, channels, more = _place(_dimms_from_edac(edac), [], cpu.sockets.value, how)
        dimms = placed
    else:
        dimms, channels, more = [], Fact.unknown("no DIMM list (neither dmidecode nor EDAC)"), []
    notes.extend(more)
    for name, fact in (("sockets", cpu.sockets), ("cores per socket", cpu.cores_per_socket),
                       ("NUMA nodes per socket", cpu.numa_nodes_per_socket), ("channels per socket", channels)):
        if not fact.known:
            notes.append(f"{name}: {fact.source}")
    return NodeDescription(
        sockets=cpu.sockets, dies_per_socket=cpu.dies_per_socket, cores_per_socket=cpu.cores_per_socket,
        threads_per_core=cpu.threads_per_core, numa_nodes_per_socket=cpu.numa_nodes_per_socket,
        channels_per_socket=channels, dimms_per_channel=_dimms_per_channel(dimms), dimms=tuple(dimms),
        cpus_by_socket=cpu.cpus_by_socket, notes=tuple(notes), cpus_by_numa=cpu.cpus_by_numa,
        channel_rule=rule.text if rule is not None and installed else None, cpu=cpu_model,
        dram_energy=detect_dram_energy(sysfs_root, cpu_model))
