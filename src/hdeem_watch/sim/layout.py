"""The simulated node's layout: sockets, cores, channels (one DIMM each) and the sensors over them.

The default is the Taurus Haswell-EP node HDEEM was built for (:data:`TAURUS`: 2 sockets × 12
cores, 4 channels per socket, DIMMs A–H, sensors DDR_AB, DDR_CD on socket 0 and DDR_EF, DDR_GH on
socket 1). :func:`layout_for_node` makes the layout of any detected or configured
:class:`~hdeem_watch.node.description.NodeDescription` with one DIMM per channel, so the sim can
stand in for a 2 × 28-core Ice Lake or a 1-socket node: DIMMs are named by the node-wide channel
letters, one sensor per pair of consecutive channels of a socket (the
:func:`~hdeem_watch.node.sensors.sensor_map` rule), one ``CPU<n>`` channel per socket.
:meth:`SimLayout.per_socket` is a node whose DRAM sensor is RAPL's, one ``DRAM<n>`` per socket over
all of its channels (:mod:`hdeem_watch.sources.rapl`'s names): :data:`SAPPHIRE_RAPIDS`, 2 sockets ×
56 cores × 8 DDR5 channels.

Example:
    >>> TAURUS.dimm_sensor
    ('DDR_AB', 'DDR_AB', 'DDR_CD', 'DDR_CD', 'DDR_EF', 'DDR_EF', 'DDR_GH', 'DDR_GH')
    >>> SimLayout.regular(1, 8, 6).sensors
    ('DDR_AB', 'DDR_CD', 'DDR_EF')
    >>> SAPPHIRE_RAPIDS.sensors, len(SAPPHIRE_RAPIDS.sensor_dimms("DRAM1"))
    (('DRAM0', 'DRAM1'), 8)
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

from hdeem_watch.channels import channel_letter, dimm_pair_channel
from hdeem_watch.dram.node import NodeTopology
from hdeem_watch.errors import InputError

if TYPE_CHECKING:
    from hdeem_watch.node.description import NodeDescription


@dataclass(frozen=True)
class SimLayout:
    """Where the simulated node's DIMMs are and which sensor sees each.

    Attributes:
        topology: sockets, cores per socket, channels per socket (one DIMM per channel).
        dimm_names: DIMM names (node-wide channel letters), in channel order.
        dimm_socket: the socket of each DIMM.
        dimm_sensor: the DRAM sensor channel that measures each DIMM.
        sensors: the DRAM sensor channels, in order.
        memspec: the DIMMs' memspec: a preset name or a memspec file of the sim package.
    """

    topology: NodeTopology
    dimm_names: tuple[str, ...]
    dimm_socket: tuple[int, ...]
    dimm_sensor: tuple[str, ...]
    sensors: tuple[str, ...] = field(default=())
    memspec: str = "samsung-m393a1g43db0-cpb"

    @classmethod
    def regular(cls, sockets: int, cores_per_socket: int, channels_per_socket: int) -> SimLayout:
        """``sockets`` × ``channels_per_socket`` DIMMs, sensors over pairs of consecutive channels."""
        topology = NodeTopology(sockets=sockets, cores_per_socket=cores_per_socket,
                                channels_per_socket=channels_per_socket)
        names, socket_of, sensor_of = [], [], []
        for s in range(sockets):
            for c in range(channels_per_socket):
                names.append(channel_letter(s * channels_per_socket + c))
                socket_of.append(s)
                sensor_of.append(dimm_pair_channel(s, c, channels_per_socket))
        sensors = tuple(dict.fromkeys(sensor_of))
        return cls(topology, tuple(names), tuple(socket_of), tuple(sensor_of), sensors)

    @classmethod
    def per_socket(cls, sockets: int, cores_per_socket: int, channels_per_socket: int) -> SimLayout:
        """``sockets`` × ``channels_per_socket`` DIMMs, one RAPL-like sensor ``DRAM<s>`` per socket."""
        regular = cls.regular(sockets, cores_per_socket, channels_per_socket)
        sensor_of = tuple(f"DRAM{s}" for s in regular.dimm_socket)
        return cls(regular.topology, regular.dimm_names, regular.dimm_socket, sensor_of,
                   tuple(dict.fromkeys(sensor_of)))

    @property
    def sockets(self) -> int:
        """Sockets."""
        return self.topology.sockets

    @property
    def cpu_channels(self) -> tuple[str, ...]:
        """``CPU0``, ``CPU1``, ... (one package power channel per socket)."""
        return tuple(f"CPU{s}" for s in range(self.sockets))

    @property
    def channels(self) -> tuple[str, ...]:
        """Every channel the sim publishes: BLADE, the CPU packages, the DRAM sensors."""
        return ("BLADE", *self.cpu_channels, *self.sensors)

    def sensor_dimms(self, sensor: str) -> list[int]:
        """Indices of the DIMMs behind ``sensor``."""
        return [d for d, s in enumerate(self.dimm_sensor) if s == sensor]


#: The Taurus Haswell-EP node (the sim's default).
TAURUS = SimLayout.regular(2, 12, 4)
#: A Sapphire Rapids-like DDR5 node: 2 sockets × 56 cores × 8 channels, RAPL DRAM per socket.
SAPPHIRE_RAPIDS = SimLayout.per_socket(2, 56, 8)
#: The DDR5 node's memspec (``sim/ddr5_node.json``): DRAMPower v6.2's DDR5 test memspec as one 32-bit
#: BL16 DDR5-4800 sub-channel (docs/sources.md says which number comes from where).
DDR5_MEMSPEC = "ddr5_node.json"
#: The simulated DDR5 node: :data:`SAPPHIRE_RAPIDS`'s sockets with DDR5 DIMMs of :data:`DDR5_MEMSPEC`;
#: its units are the 2 × 8 sub-channels of each socket's 8 DIMMs (the memspec describes one).
DDR5_NODE = replace(SimLayout.per_socket(2, 56, 16), memspec=DDR5_MEMSPEC)


#: The simulated nodes by name (``hdeem-watch demo --node``, the daemon's ``sim_node`` setting).
SIM_NODES: dict[str, SimLayout] = {"haswell": TAURUS, "ddr5": DDR5_NODE}


def sim_node(name: str) -> SimLayout:
    """The simulated node called ``name`` (:data:`SIM_NODES`).

    Raises:
        InputError: an unknown name (one line with the known ones).

    Example:
        >>> sim_node("ddr5").sensors
        ('DRAM0', 'DRAM1')
    """
    layout = SIM_NODES.get(str(name).strip().lower())
    if layout is None:
        raise InputError(f"sim node {name!r}: unknown; expected one of {', '.join(SIM_NODES)}")
    return layout


def layout_for_node(node: NodeDescription) -> SimLayout:
    """The sim layout of a node description (sockets, cores and channels must be known).

    Raises:
        InputError: a count the description does not know, or more than one DIMM per channel
            (the sim models one DIMM per channel).
    """
    missing = [name for name, fact in (("sockets", node.sockets), ("cores_per_socket", node.cores_per_socket),
                                       ("channels_per_socket", node.channels_per_socket)) if fact.value is None]
    if missing:
        raise InputError(f"sim: the node description does not know {', '.join(missing)}; set them in the [node] table")
    dpc = node.dimms_per_channel.value
    if dpc is not None and dpc != 1:
        raise InputError(f"sim: {dpc} DIMMs per channel; the simulated node models one DIMM per channel")
    return SimLayout.regular(int(node.sockets.value or 0), int(node.cores_per_socket.value or 0),
                             int(node.channels_per_socket.value or 0))
