"""The ``[node]`` table of the daemon's TOML: what cannot be detected, set by hand.

Keys (all optional)::

    [node]
    name = "taurusi1234"                       # the node's name (else the top-level/[daemon] node key, the host name)
    sockets = 2
    cores_per_socket = 12
    threads_per_core = 2
    numa_nodes_per_socket = 1
    channels_per_socket = 4
    dimms_per_channel = 1
    memspec = "samsung-m393a1g43db0-cpb"      # a preset name or a DRAMPower JSON file
    dmidecode = "/etc/hdeem-watch/dmi.txt"     # a saved `dmidecode -t 17` (a daemon that is not root)
    [node.dimm]                                # every DIMM (homogeneous nodes)
    part_number = "M393A1G43DB0-CPB"
    size_gb = 8
    ranks = 2
    speed_mts = 2133
    device_width = 8
    [node.sensors]                             # sensor -> DIMM locators
    DDR_AB = ["P1-DIMMA1", "P1-DIMMB1"]

The top-level ``node = "NAME"`` of older config files is still the node's name: TOML cannot hold
that key and a ``[node]`` table in one file, so a file with the table puts the name in it (``name``)
or in the ``[daemon]`` table (:func:`split_node_entry`).

When the node shows no DIMM at all (a VM, no root for dmidecode, no EDAC), sockets ×
channels_per_socket × dimms_per_channel DIMMs are made up from ``[node.dimm]``, named ``S0-A1`` ...

Example:
    >>> parse_node_table({"sockets": 2, "dimm": {"ranks": 2}}).counts
    {'sockets': 2}
    >>> parse_node_table({"socket": 2})
    Traceback (most recent call last):
    hdeem_watch.errors.InputError: [node]: unknown key 'socket'; expected one of channels_per_socket, cores_per_socket, dies_per_socket, dimm, dimms_per_channel, dmidecode, memspec, name, numa_nodes_per_socket, sensors, sockets, threads_per_core
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from hdeem_watch.errors import InputError
from hdeem_watch.node.description import Dimm, NodeDescription
from hdeem_watch.node.facts import Fact

COUNT_KEYS = ("sockets", "dies_per_socket", "cores_per_socket", "threads_per_core", "numa_nodes_per_socket",
              "channels_per_socket", "dimms_per_channel")
DIMM_KEYS = {"part_number": str, "size_gb": int, "ranks": int, "speed_mts": int, "device_width": int,
             "type": str, "manufacturer": str}
SOURCE = "config [node]"


@dataclass(frozen=True)
class NodeOverrides:
    """The parsed ``[node]`` table.

    Attributes:
        counts: count name → value.
        memspec: a preset name or memspec file (``None``: choose from the DIMMs).
        dimm: DIMM field → value (``[node.dimm]``).
        sensors: sensor → DIMM locators (``[node.sensors]``).
    """

    counts: dict[str, int] = field(default_factory=dict)
    memspec: str | None = None
    dimm: dict[str, Any] = field(default_factory=dict)
    sensors: dict[str, list[str]] = field(default_factory=dict)
    name: str | None = None
    dmidecode: str | None = None

    @property
    def empty(self) -> bool:
        """Whether the table sets nothing about the hardware (at most the name)."""
        return not (self.counts or self.memspec or self.dimm or self.sensors or self.dmidecode)


def split_node_entry(entry: Any) -> tuple[Mapping[str, Any] | None, str | None]:
    """A config file's top-level ``node`` entry as ``(hardware table, name)``.

    ``node = "n7"`` (the older spelling) is the name alone; a ``[node]`` table is the hardware
    (its ``name`` key, when present, is the name too); nothing is ``(None, None)``.

    Example:
        >>> split_node_entry("n7")
        (None, 'n7')
        >>> split_node_entry({"name": "n7", "sockets": 2})
        ({'name': 'n7', 'sockets': 2}, 'n7')
    """
    if entry is None:
        return None, None
    if isinstance(entry, Mapping):
        name = entry.get("name")
        return entry, name if isinstance(name, str) else None
    return None, entry if isinstance(entry, str) else None


def _positive(where: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise InputError(f"{where} = {value!r}: expected a positive integer")
    return value


def parse_node_table(table: Mapping[str, Any], where: str = "[node]") -> NodeOverrides:
    """Validate a ``[node]`` table (as ``tomllib`` parsed it).

    Raises:
        InputError: an unknown key or a value of the wrong kind, named in one line.
    """
    if not isinstance(table, Mapping):
        raise InputError(f"{where}: expected a table, got {type(table).__name__}")
    known = (*COUNT_KEYS, "memspec", "dimm", "sensors", "name", "dmidecode")
    for key in table:
        if key not in known:
            raise InputError(f"{where}: unknown key {key!r}; expected one of {', '.join(sorted(known))}")
    counts = {k: _positive(f"{where}.{k}", table[k]) for k in COUNT_KEYS if k in table}
    name = table.get("name")
    if name is not None and (not isinstance(name, str) or not name or "/" in name):
        raise InputError(f"{where}.name = {name!r}: expected a non-empty node name without '/'")
    memspec = table.get("memspec")
    if memspec is not None and (not isinstance(memspec, str) or not memspec):
        raise InputError(f"{where}.memspec = {memspec!r}: expected a preset name or a memspec file")
    dmidecode = table.get("dmidecode")
    if dmidecode is not None and (not isinstance(dmidecode, str) or not dmidecode):
        raise InputError(f"{where}.dmidecode = {dmidecode!r}: expected the path of a saved 'dmidecode -t 17' print-out")
    dimm_table = table.get("dimm", {})
    if not isinstance(dimm_table, Mapping):
        raise InputError(f"{where}.dimm: expected a table")
    dimm: dict[str, Any] = {}
    for key, value in dimm_table.items():
        kind = DIMM_KEYS.get(key)
        if kind is None:
            raise InputError(f"{where}.dimm: unknown key {key!r}; expected one of {', '.join(sorted(DIMM_KEYS))}")
        dimm[key] = _positive(f"{where}.dimm.{key}", value) if kind is int else value
        if kind is str and not isinstance(value, str):
            raise InputError(f"{where}.dimm.{key} = {value!r}: expected a string")
    sensors_table = table.get("sensors", {})
    if not isinstance(sensors_table, Mapping):
        raise InputError(f"{where}.sensors: expected a table of sensor = [DIMM locators]")
    sensors: dict[str, list[str]] = {}
    for name, locators in sensors_table.items():
        if not isinstance(locators, list) or not all(isinstance(x, str) for x in locators):
            raise InputError(f"{where}.sensors.{name} = {locators!r}: expected a list of DIMM locators")
        sensors[name] = list(locators)
    return NodeOverrides(counts=counts, memspec=memspec, dimm=dimm, sensors=sensors, name=name, dmidecode=dmidecode)


def _dimm_values(dimm: Mapping[str, Any]) -> dict[str, Any]:
    values = {k: v for k, v in dimm.items() if k not in ("size_gb",)}
    if "size_gb" in dimm:
        values["size_bytes"] = int(dimm["size_gb"]) << 30
    return values


def apply_overrides(node: NodeDescription, overrides: NodeOverrides) -> NodeDescription:
    """``node`` with the configured facts in place of the detected ones (tagged ``config [node]``)."""
    facts = {k: Fact(v, SOURCE) for k, v in overrides.counts.items()}
    out = node.with_facts(**facts)
    values = _dimm_values(overrides.dimm)
    dimms = list(out.dimms)
    if dimms and values:
        dimms = [replace(d, **values, sources={**d.sources, **dict.fromkeys(values, SOURCE)}) for d in dimms]
    elif not dimms:
        sockets, channels, per = (out.sockets.value, out.channels_per_socket.value, out.dimms_per_channel.value)
        if sockets and channels and per and (values or overrides.counts):
            dimms = [Dimm(f"S{s}-{chr(ord('A') + c)}{slot + 1}", socket=s, channel=c, slot=slot, **values,
                          sources=dict.fromkeys(("socket", "channel", "slot", *values), SOURCE))
                     for s in range(sockets) for c in range(channels) for slot in range(per)]
    notes = tuple(n for n in out.notes if not any(n.startswith(k.replace("_", " ")) for k in overrides.counts))
    return replace(out, dimms=tuple(dimms), notes=notes)
