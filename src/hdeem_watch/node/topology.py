"""The model's view of a node: a :class:`~hdeem_watch.dram.node.NodeTopology` from its description.

:func:`topology_from_node` takes the counts the model needs from a detected or configured
:class:`~hdeem_watch.node.description.NodeDescription`: sockets, cores per socket, memory channels
per socket and DIMMs per channel must be known (set them in the ``[node]`` table where they cannot
be detected); NUMA nodes per socket, threads per core and DIMMs per channel default to 1 when
unknown, and the ranks are the DIMMs' when they all agree (else the memspec's). Each logical CPU's
memory domain comes from the socket CPU lists sysfs gave; with SNC/NPS from the kernel's NUMA node
CPU lists (``node*/cpulist``), or, where those do not fit the counts (e.g. a ``[node]`` override),
from a socket's cores split evenly over its NUMA nodes in order.

Example:
    >>> from hdeem_watch.node.description import NodeDescription
    >>> from hdeem_watch.node.facts import Fact
    >>> one, n = Fact(1, "t"), lambda v: Fact(v, "t")
    >>> node = NodeDescription(n(2), one, n(28), n(2), one, n(8), n(2))
    >>> topology_from_node(node).dimms
    32
"""

from __future__ import annotations

from hdeem_watch.dram.node import NodeTopology
from hdeem_watch.errors import InputError
from hdeem_watch.node.description import NodeDescription


def _numa_domains(node: NodeDescription, numa_per_socket: int) -> dict[int, int] | None:
    """CPU → domain from the kernel's NUMA node CPU lists, when each node lies on one socket and
    every socket has ``numa_per_socket`` of them (else None)."""
    socket_of = {cpu: int(s) for s, cpus in node.cpus_by_socket.items() for cpu in cpus}
    nodes_of: dict[int, list[int]] = {}
    for numa, cpus in sorted(node.cpus_by_numa.items()):
        sockets = {socket_of.get(c) for c in cpus}
        if len(sockets) != 1 or None in sockets:
            return None
        nodes_of.setdefault(int(sockets.pop() or 0), []).append(numa)
    if not nodes_of or any(len(v) != numa_per_socket for v in nodes_of.values()):
        return None
    return {cpu: socket * numa_per_socket + nodes.index(numa)
            for socket, nodes in nodes_of.items() for numa in nodes for cpu in node.cpus_by_numa[numa]}


def _cpu_domains(node: NodeDescription, cores_per_socket: int, numa_per_socket: int) -> tuple[int, ...]:
    """Memory domain of each logical CPU (``-1``: no such CPU): the kernel's NUMA CPU lists, else the
    socket CPU lists with each socket's cores split evenly over its NUMA nodes."""
    if not node.cpus_by_socket:
        return ()
    highest = max((c for cpus in node.cpus_by_socket.values() for c in cpus), default=-1)
    domains = [-1] * (highest + 1)
    by_numa = _numa_domains(node, numa_per_socket) if numa_per_socket > 1 else None
    for socket, cpus in node.cpus_by_socket.items():
        for position, cpu in enumerate(sorted(cpus)):
            core = position % cores_per_socket  # SMT siblings come after every core's first thread
            default = int(socket) * numa_per_socket + core * numa_per_socket // cores_per_socket
            domains[cpu] = by_numa.get(cpu, default) if by_numa is not None else default
    return tuple(domains)


def topology_from_node(node: NodeDescription) -> NodeTopology:
    """The model's topology of ``node``.

    Raises:
        InputError: a count the model needs is unknown (naming the ``[node]`` key to set), or the
            counts do not fit together (e.g. NUMA nodes that do not divide the channels).
    """
    needed = {"sockets": node.sockets, "cores_per_socket": node.cores_per_socket,
              "channels_per_socket": node.channels_per_socket}
    missing = [name for name, fact in needed.items() if fact.value is None]
    if missing:
        raise InputError(f"node: {', '.join(missing)} unknown ({needed[missing[0]].source}); "
                         f"set {', '.join(missing)} in the [node] table")
    sockets = int(node.sockets.value or 0)
    cores = int(node.cores_per_socket.value or 0)
    numa = int(node.numa_nodes_per_socket.value or 1)
    ranks = {d.ranks for d in node.dimms if d.ranks is not None}
    cpu_domains = _cpu_domains(node, cores, numa)
    if cpu_domains and max(cpu_domains) >= sockets * numa:
        cpu_domains = ()  # socket ids beyond the socket count (a partial override): the default numbering
    return NodeTopology(
        sockets=sockets, cores_per_socket=cores, channels_per_socket=int(node.channels_per_socket.value or 0),
        dimms_per_channel=int(node.dimms_per_channel.value or 1), numa_nodes_per_socket=numa,
        threads_per_core=int(node.threads_per_core.value or 1),
        ranks_per_dimm=ranks.pop() if len(ranks) == 1 else None, cpu_domains=cpu_domains)
