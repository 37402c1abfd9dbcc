"""A whole node's DRAM traffic: which channels a run's threads load, and their command statistics.

The simulated node (:mod:`hdeem_watch.sim.model`) and the daemon's calibration row
(:mod:`hdeem_watch.calibrate.run_model`) must model a run the same way, so both call
:func:`node_run_stats`. The node (:class:`NodeTopology`, default :data:`HASWELL_EP`: the Taurus
blade, 2 sockets × 12 cores, 4 memory channels per socket, one DIMM each; any other node from its
description with :func:`hdeem_watch.node.topology.topology_from_node`) is cut into **memory
domains**: one per NUMA node, i.e. per socket, or per sub-NUMA cluster (SNC/NPS) where a socket
has several, each with ``channels_per_socket / numa_nodes_per_socket`` channels.

Where the threads run:

- an announced CPU list (``bench`` sends the CPUs it pinned to): each CPU's domain from the node's
  CPU numbering (:attr:`NodeTopology.cpu_domains`; without one the Linux default: CPU ``i`` on
  socket ``(i // cores_per_socket) % sockets``, SMT siblings after all first threads);
- no list (an older bench, a SLURM job): ``threads`` threads fill socket 0's cores first, then
  socket 1's, ... (as the seed paper observed), hyper-threads after every core is taken.

Each domain's threads work on their share of the arrays (OpenMP ``static``: elements in
proportion to the threads); first-touch places it in that domain's memory, and its controller
spreads it over the domain's channels and, with several DIMMs per channel, over their DIMMs: one
DIMM's statistics are :func:`hdeem_watch.dram.kernels.kernel_stats` of the domain's threads and
elements with ``channels = channels × DIMMs per channel`` and XOR bank hashing (Haswell-EP and later
controllers hash banks; without it every thread's power-of-two chunk starts in the same bank). Two
DIMMs sharing a channel share its bus; the model keeps their command counts exact and leaves the
longer busy time to the measured window (background residency is stretched to it). A domain
without threads is an idle group: statistics with no commands (its DIMMs idle).

The calibrator turns the groups into ONE calibration row against the node's total DRAM energy
(:func:`hdeem_watch.calibrate.rows.node_observation`), or one row per sensor
(:func:`hdeem_watch.node.sensor_stats.sensor_run_stats`).

Example:
    >>> NodeTopology().threads_per_socket(18)
    (12, 6)
    >>> NodeTopology(sockets=2, cores_per_socket=28, channels_per_socket=8).domain_threads(28, cpus=range(28, 56))
    (0, 28)
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from hdeem_watch.dram.memspec import MemSpec
from hdeem_watch.dram.stats import CommandStats, RankStats
from hdeem_watch.errors import InputError

#: Kernel names that move no DRAM traffic (idle and compute-only runs): their channels are modelled
#: as idle groups whatever the run's size.
NO_TRAFFIC_KERNELS = ("idle", "sleep", "compute", "none")

_COUNTS = ("sockets", "cores_per_socket", "channels_per_socket", "dimms_per_channel", "numa_nodes_per_socket",
           "threads_per_core")


@dataclass(frozen=True)
class NodeTopology:
    """Sockets, cores, NUMA domains, memory channels and DIMMs of a node.

    Attributes:
        sockets: CPU sockets.
        cores_per_socket: physical cores per socket (logical CPUs beyond ``sockets × cores`` are
            hyper-threads, placed the same way).
        channels_per_socket: memory channels per socket.
        dimms_per_channel: DIMMs on each channel.
        numa_nodes_per_socket: NUMA nodes per socket (> 1: SNC/NPS; must divide the channels).
        threads_per_core: hardware threads per core.
        ranks_per_dimm: ranks of each DIMM (None: the memspec's).
        cpu_domains: memory domain of each logical CPU (index = CPU id; ``-1`` = not present);
            empty = the Linux default numbering.
    """

    sockets: int = 2
    cores_per_socket: int = 12
    channels_per_socket: int = 4
    dimms_per_channel: int = 1
    numa_nodes_per_socket: int = 1
    threads_per_core: int = 1
    ranks_per_dimm: int | None = None
    cpu_domains: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        for name in _COUNTS:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise InputError(f"topology.{name}: {value!r}; expected an integer >= 1")
        if self.channels_per_socket % self.numa_nodes_per_socket:
            raise InputError(f"topology: {self.numa_nodes_per_socket} NUMA nodes per socket do not divide "
                             f"{self.channels_per_socket} channels per socket; expected a divisor")
        if self.ranks_per_dimm is not None and (isinstance(self.ranks_per_dimm, bool) or self.ranks_per_dimm < 1):
            raise InputError(f"topology.ranks_per_dimm: {self.ranks_per_dimm!r}; expected an integer >= 1 or None")
        bad = [d for d in self.cpu_domains if not -1 <= d < self.domains]
        if bad:
            raise InputError(f"topology.cpu_domains: domain {bad[0]!r}; expected -1..{self.domains - 1}")

    @property
    def channels(self) -> int:
        """Memory channels of the node."""
        return self.sockets * self.channels_per_socket

    @property
    def dimms(self) -> int:
        """DIMMs of the node."""
        return self.channels * self.dimms_per_channel

    @property
    def domains(self) -> int:
        """Memory domains (NUMA nodes) of the node."""
        return self.sockets * self.numa_nodes_per_socket

    @property
    def channels_per_domain(self) -> int:
        """Memory channels of one domain."""
        return self.channels_per_socket // self.numa_nodes_per_socket

    @property
    def dimms_per_domain(self) -> int:
        """DIMMs of one domain."""
        return self.channels_per_domain * self.dimms_per_channel

    def socket_of_domain(self, domain: int) -> int:
        """The socket of memory domain ``domain``."""
        return int(domain) // self.numa_nodes_per_socket

    def domain_of_channel(self, socket: int, channel: int) -> int:
        """The memory domain of channel ``channel`` (0-based within the socket) of ``socket``."""
        return int(socket) * self.numa_nodes_per_socket + int(channel) // self.channels_per_domain

    def domain_of_cpu(self, cpu: int) -> int:
        """The memory domain of logical CPU ``cpu``.

        Raises:
            InputError: a CPU the node does not have.
        """
        cpu = int(cpu)
        if self.cpu_domains:
            if not 0 <= cpu < len(self.cpu_domains) or self.cpu_domains[cpu] < 0:
                raise InputError(f"cpu {cpu}: not a CPU of this node (it has "
                                 f"{sum(d >= 0 for d in self.cpu_domains)} CPUs)")
            return self.cpu_domains[cpu]
        logical = self.sockets * self.cores_per_socket * self.threads_per_core
        if not 0 <= cpu < logical:
            raise InputError(f"cpu {cpu}: not a CPU of this node; expected 0..{logical - 1}")
        socket = (cpu // self.cores_per_socket) % self.sockets
        core = cpu % self.cores_per_socket
        return socket * self.numa_nodes_per_socket + core * self.numa_nodes_per_socket // self.cores_per_socket

    def threads_per_socket(self, threads: int) -> tuple[int, ...]:
        """Threads on each socket when ``threads`` threads fill socket 0's cores first."""
        n = max(0, int(threads))
        full, rest = divmod(n, self.cores_per_socket)
        counts = [0] * self.sockets
        for block in range(full):
            counts[block % self.sockets] += self.cores_per_socket
        if rest:
            counts[full % self.sockets] += rest
        return tuple(counts)

    def domain_threads(self, threads: int, cpus: Iterable[int] | None = None) -> tuple[int, ...]:
        """Threads in each memory domain: from the CPU list when given (one thread per entry), else
        ``threads`` threads filling socket 0 first (cores split evenly over a socket's domains).

        Raises:
            InputError: a CPU the node does not have.
        """
        counts = [0] * self.domains
        if cpus is not None:
            for cpu in cpus:
                counts[self.domain_of_cpu(cpu)] += 1
            return tuple(counts)
        k = self.numa_nodes_per_socket
        for socket, n in enumerate(self.threads_per_socket(threads)):
            for core in range(n):  # the socket's threads on its cores in order (wrapping for SMT)
                counts[socket * k + (core % self.cores_per_socket) * k // self.cores_per_socket] += 1
        return tuple(counts)

    def shares(self, threads: int) -> tuple[float, ...]:
        """Fraction of a run's traffic on each socket (proportional to its threads)."""
        counts = self.threads_per_socket(threads)
        total = sum(counts)
        return tuple(c / total if total else 0.0 for c in counts)


#: The modelled Haswell-EP node of DESIGN.md §5 (the Taurus blade: the default everywhere).
HASWELL_EP = NodeTopology()


def topology_for(dimms: int) -> NodeTopology:
    """The legacy guess from a DIMM count alone (2 sockets × 12 cores, 1 socket if ``dimms`` is odd).

    Only for callers that know nothing but the DIMM count (old reports); the daemon takes its
    topology from the node description (:func:`hdeem_watch.node.topology.topology_from_node`).
    """
    dimms = int(dimms)
    if dimms < 1:
        raise InputError(f"dimms: {dimms!r}; expected an integer >= 1")
    if dimms % 2:
        return NodeTopology(sockets=1, cores_per_socket=24, channels_per_socket=dimms)
    return NodeTopology(sockets=2, cores_per_socket=12, channels_per_socket=dimms // 2)


def idle_channel_stats(spec: MemSpec) -> CommandStats:
    """One channel without commands (one empty rank per rank of ``spec``): the calibrator turns it
    into precharged standby with a refresh every REFI over the measured window."""
    return CommandStats(ranks=tuple(RankStats() for _ in range(int(spec.nbr_of_ranks))))


def socket_elements(elements: int, threads: int, socket_threads: int) -> int:
    """Elements the ``socket_threads`` of a socket work on (their share of ``elements``)."""
    if threads <= 0:
        return 0
    return round(int(elements) * socket_threads / threads)


#: Address-mapping families a node may use (scheme, XOR bank hash); the first is the model's own.
#: Nothing but counters tells which one a node has: the calibration carries the spread of the
#: activation counts over these into its intervals (:mod:`hdeem_watch.calibrate.trust`).
MAPPING_FAMILIES: tuple[tuple[str, bool], ...] = (
    ("RoBaRaCoCh", True), ("RoBaRaCoCh", False), ("ChRaBaRoCo", True), ("RoRaBgBaCoCh", True))


def node_run_stats(spec: MemSpec, kernel: str, elements: int, threads: int, repeat: int,
                   topology: NodeTopology = HASWELL_EP, *, cpus: Sequence[int] | None = None,
                   xor_bank: bool = True, max_requests: int | None = None,
                   mapping: str = "RoBaRaCoCh") -> list[tuple[CommandStats, int]]:
    """Per memory domain (in order: socket 0's, then socket 1's, ...; one per socket without SNC),
    the statistics of ONE of its DIMMs and how many DIMMs it has.

    Args:
        spec: memspec of one DIMM.
        kernel: kernel name (one of :data:`NO_TRAFFIC_KERNELS` = no traffic).
        elements: doubles per array (of the whole run).
        threads: threads of the run (ignored when ``cpus`` is given).
        repeat: passes.
        topology: the node.
        cpus: the logical CPUs the run's threads were pinned to, one entry per thread (None:
            threads fill socket 0 first).
        xor_bank: XOR bank hashing in the channels' address mapping.
        max_requests: prefix size of the kernel model (None = its default).
        mapping: the channels' address-mapping scheme (:data:`MAPPING_FAMILIES`).

    Returns:
        ``[(stats, dimms), ...]``, one entry per domain; a domain without traffic is an idle
        group (:func:`idle_channel_stats`).

    Raises:
        InputError: an unknown kernel, a bad size, or a CPU the node does not have.
    """
    from hdeem_watch.dram.kernels import kernel_stats

    idle = idle_channel_stats(spec)
    counts = topology.domain_threads(threads, cpus)
    total = sum(counts)
    no_traffic = str(kernel).strip().lower() in NO_TRAFFIC_KERNELS or int(elements) <= 0 or int(repeat) <= 0
    per_domain = topology.dimms_per_domain
    groups: list[tuple[CommandStats, int]] = []
    for domain_threads in counts:
        n_elements = socket_elements(elements, total, domain_threads)
        if no_traffic or domain_threads == 0 or n_elements <= 0:
            groups.append((idle, per_domain))
            continue
        options: dict[str, Any] = {"repeat": int(repeat), "channels": per_domain, "xor_bank": xor_bank,
                                   "mapping": mapping}
        if max_requests:
            options["max_requests"] = int(max_requests)
        stats = kernel_stats(spec, kernel, n_elements, domain_threads, **options).stats
        groups.append((stats, per_domain))
    return groups


def lines_of(stats: CommandStats) -> float:
    """64-byte lines (read and write bursts) in ``stats``."""
    return sum(stats.total(f) for f in ("rd", "wr", "rda", "wra"))


def cycles_per_line(stats: CommandStats) -> float:
    """Controller cycles per line of a channel's statistics (NaN without traffic)."""
    lines = lines_of(stats)
    cycles = max((rank.cycles_total for rank in stats.ranks), default=0.0)
    return cycles / lines if lines > 0 else float("nan")


def node_capacity_lines_s(spec: MemSpec, groups: Sequence[tuple[CommandStats, int]]) -> list[float]:
    """Per group, the lines/s its channels can serve (channels / (cycles per line × tCK); 0 if idle)."""
    out = []
    for stats, channels in groups:
        cpl = cycles_per_line(stats)
        out.append(channels / (cpl * float(spec.tck_s)) if cpl == cpl and cpl > 0 else 0.0)
    return out


def node_counts(groups: Sequence[tuple[CommandStats, int]]) -> dict[str, float]:
    """Node totals of the command counts (ACT, PRE, RD, WR, REF of the model, all channels)."""
    return {f: float(sum(stats.total(f) * n for stats, n in groups)) for f in ("act", "pre", "rd", "wr", "ref")}
