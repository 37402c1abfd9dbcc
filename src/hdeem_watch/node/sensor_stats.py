"""A run's command statistics per power sensor: what each sensor's DIMMs did, for per-sensor rows.

The model of a run (:func:`hdeem_watch.dram.node.node_run_stats`) gives, per memory domain (a
socket, or a NUMA node of it under SNC/NPS), the statistics of ONE of its DIMMs. A sensor measures
some DIMMs (:func:`hdeem_watch.node.sensors.sensor_map`: HDEEM ``DDR_AB`` = socket 0 channels A
and B, RAPL ``DRAM<n>`` = socket n's DIMMs); :func:`split_by_sensor` gives each sensor its
domains' one-DIMM statistics with the number of its DIMMs in each domain. That list has the shape
:func:`hdeem_watch.calibrate.rows.node_observation` takes, so one sensor's calibration row is::

    rows = split_by_sensor(topology, node_run_stats(spec, kernel, n, threads, repeat, topology, cpus=cpus),
                           sensor_map(node), dimm_channels(node))
    obs = node_observation(spec, rows["DDR_AB"], window_s, energy_j["DDR_AB"])

Pure: no I/O; :func:`sensor_run_stats` does the whole chain for a node description.

Example:
    >>> from hdeem_watch.dram.node import NodeTopology
    >>> from hdeem_watch.dram.stats import CommandStats
    >>> busy, idle = CommandStats(ranks=()), CommandStats(ranks=())
    >>> rows = split_by_sensor(NodeTopology(), [(busy, 4), (idle, 4)], {"DDR_AB": ["A", "B"], "DDR_EF": ["E"]},
    ...                        {"A": (0, 0), "B": (0, 1), "E": (1, 0)})
    >>> [(stats is busy, n) for stats, n in rows["DDR_AB"]], [(stats is idle, n) for stats, n in rows["DDR_EF"]]
    ([(True, 2)], [(True, 1)])
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from hdeem_watch.dram.memspec import MemSpec
from hdeem_watch.dram.node import NodeTopology, node_run_stats
from hdeem_watch.dram.stats import CommandStats
from hdeem_watch.errors import InputError
from hdeem_watch.node.description import NodeDescription
from hdeem_watch.node.sensors import sensor_map
from hdeem_watch.node.topology import topology_from_node

SensorRows = dict[str, list[tuple[CommandStats, int]]]


def dimm_channels(node: NodeDescription) -> dict[str, tuple[int, int]]:
    """DIMM locator → (socket, channel within the socket), for the DIMMs whose place is known."""
    return {d.locator: (d.socket, d.channel) for d in node.dimms if d.socket is not None and d.channel is not None}


def split_by_sensor(topology: NodeTopology, groups: Sequence[tuple[CommandStats, int]],
                    sensors: Mapping[str, Sequence[str]], channels: Mapping[str, tuple[int, int]]) -> SensorRows:
    """Per sensor, ``[(one DIMM's statistics, the sensor's DIMMs there), ...]`` over the domains it sees.

    Args:
        topology: the node (its memory domains).
        groups: :func:`~hdeem_watch.dram.node.node_run_stats` of the run on ``topology`` (one per domain).
        sensors: sensor → DIMM locators (:func:`~hdeem_watch.node.sensors.sensor_map`, or configured).
        channels: DIMM locator → (socket, channel) (:func:`dimm_channels`).

    Raises:
        InputError: ``groups`` is not one per domain, a sensor names a DIMM without a known place or
            one outside the topology, or a sensor measures no DIMM.
    """
    if len(groups) != topology.domains:
        raise InputError(f"sensor rows: {len(groups)} model groups; the node has {topology.domains} memory domains")
    out: SensorRows = {}
    for sensor, locators in sensors.items():
        per_domain = [0] * topology.domains
        for locator in locators:
            place = channels.get(locator)
            if place is None:
                raise InputError(f"sensor map: {sensor}: DIMM {locator!r} has no known socket and channel; "
                                 "expected a DIMM of the node description")
            socket, channel = place
            if not (0 <= socket < topology.sockets and 0 <= channel < topology.channels_per_socket):
                raise InputError(f"sensor map: {sensor}: DIMM {locator!r} on socket {socket} channel {channel}; "
                                 f"the node has {topology.sockets} sockets × {topology.channels_per_socket} channels")
            per_domain[topology.domain_of_channel(socket, channel)] += 1
        if not any(per_domain):
            raise InputError(f"sensor map: {sensor}: measures no DIMM")
        out[sensor] = [(groups[d][0], k) for d, k in enumerate(per_domain) if k > 0]
    return out


def sensor_run_stats(spec: MemSpec, node: NodeDescription, kernel: str, elements: int, threads: int,
                     repeat: int, *, cpus: Sequence[int] | None = None,
                     sensors: Mapping[str, Sequence[str]] | None = None,
                     max_requests: int | None = None) -> SensorRows:
    """The model of one run on ``node``, split per sensor (see the module docstring).

    Args:
        spec: memspec of one DIMM.
        node: the node description (its topology and DIMM places).
        kernel, elements, threads, repeat: the run.
        cpus: the CPUs its threads were pinned to (None: threads fill socket 0 first).
        sensors: sensor → DIMM locators (default :func:`~hdeem_watch.node.sensors.sensor_map` of ``node``).
        max_requests: prefix size of the kernel model (None = its default).

    Raises:
        InputError: an unknown count of the node, a bad run or a bad sensor map.
    """
    topology = topology_from_node(node)
    groups = node_run_stats(spec, kernel, elements, threads, repeat, topology, cpus=cpus, max_requests=max_requests)
    return split_by_sensor(topology, groups, sensor_map(node) if sensors is None else sensors, dimm_channels(node))
