"""The node report behind ``hdeem-watch node``: description, memspec choice, sensor map and what the
run model makes of the node (``model``: memory domains, DIMMs) as JSON.

Example:
    >>> from pathlib import Path
    >>> report = node_report(describe_node(Path("/nonexistent"), None, "not given"))
    >>> sorted(k for k in report if k in ("sockets", "dimms", "memspec", "sensors"))
    ['dimms', 'memspec', 'sensors', 'sockets']
"""

from __future__ import annotations

from typing import Any

from hdeem_watch.errors import InputError
from hdeem_watch.node.cpu_model import memory_controller
from hdeem_watch.node.description import NodeDescription, describe_node
from hdeem_watch.node.memspec_choice import MemspecChoice, choose_memspec
from hdeem_watch.node.overrides import NodeOverrides
from hdeem_watch.node.sensors import sensor_map
from hdeem_watch.node.topology import topology_from_node

__all__ = ["describe_node", "node_report"]


def node_report(node: NodeDescription, overrides: NodeOverrides | None = None) -> dict[str, Any]:
    """One JSON object: every count (plain and with its source), the DIMMs, memspec, sensors, notes.

    Args:
        node: the (overridden) description.
        overrides: the ``[node]`` table, for a configured memspec and sensor map.
    """
    if overrides is not None and overrides.memspec:
        choice = MemspecChoice(overrides.memspec, "set in the [node] table", "configured")
    else:
        choice = choose_memspec(node.dimms, cpu=node.cpu)
    sensors = sensor_map(node)
    if overrides is not None and overrides.sensors:
        sensors = {**sensors, **overrides.sensors}
    facts = node.facts()
    out: dict[str, Any] = {name: fact.value for name, fact in facts.items()}
    out["facts"] = {name: fact.to_json() for name, fact in facts.items()}
    out["channel_rule"] = node.channel_rule
    controller = memory_controller(node.cpu)
    out["cpu"] = None if node.cpu is None else {
        "name": node.cpu.name, "source": node.cpu.source,
        "memory_controller": None if controller is None else {
            "generation": controller.generation, "channels_per_socket": controller.channels_per_socket,
            "memory_types": list(controller.memory_types)}}
    out["cpus_by_socket"] = {str(s): cpus for s, cpus in sorted(node.cpus_by_socket.items())}
    out["dimms"] = [d.to_json(node.channel_letter(d)) for d in node.dimms]
    out["memspec"] = choice.to_json()
    out["dram_energy"] = dram_energy_view(node, choice)
    out["sensors"] = sensors
    out["cpus_by_numa"] = {str(n): cpus for n, cpus in sorted(node.cpus_by_numa.items())}
    out["model"] = model_view(node)
    out["notes"] = list(node.notes)
    return out


def model_view(node: NodeDescription) -> dict[str, Any]:
    """What the daemon's run model makes of the node (``model`` in ``--json``): its memory domains
    (NUMA nodes) with their channels and DIMMs, or why it cannot model it (``error``)."""
    try:
        topo = topology_from_node(node)
    except InputError as error:
        return {"error": str(error)}
    return {"error": None, "sockets": topo.sockets, "memory_domains": topo.domains,
            "channels_per_domain": topo.channels_per_domain, "dimms_per_channel": topo.dimms_per_channel,
            "dimms": topo.dimms, "ranks_per_dimm": topo.ranks_per_dimm,
            "cpu_numbering": "sysfs" if topo.cpu_domains else "default (CPU i on socket (i // cores) % sockets)"}


def dram_energy_view(node: NodeDescription, choice: MemspecChoice) -> dict[str, Any] | None:
    """``dram_energy`` in ``--json``: the sensor (RAPL zones) or, without one, what models the DRAM energy
    and with which currents (``currents``: ``datasheet`` of a preset, ``memspec file`` as configured, or
    ``none`` while no memspec is known)."""
    if node.dram_energy is None:
        return None
    out = node.dram_energy.to_json()
    if node.dram_energy.sensor is None and node.dram_energy.model is not None:
        if choice.confidence == "configured":
            out["currents"] = (f"memspec file {choice.name}: its currents (datasheet values, or a calibrated "
                               f"memspec imported from a node that has DRAM sensors)")
        elif choice.name is not None:
            out["currents"] = f"datasheet: preset {choice.name}"
        else:
            out["currents"] = "none: no memspec for these DIMMs yet (see memspec.reason); nothing is modelled"
    return out
