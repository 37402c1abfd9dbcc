"""A whole node's DRAM traffic: which channels a run's threads load, and their command statistics.

The simulated node (:mod:`hdeem_watch.sources.sim_model`) and the daemon's calibration row
(:mod:`hdeem_watch.daemon.modelling`) must model a run the same way, so both call
:func:`node_run_stats`. The node (:class:`NodeTopology`, default a 2-socket Haswell-EP with 12 cores
and 4 memory channels, one DIMM each, per socket) runs ``threads`` threads pinned in order: logical
CPU ``i`` sits on socket ``(i // cores_per_socket) % sockets`` (threads fill socket 0 first, as the
seed paper observed). Each socket's threads work on their share of the arrays (OpenMP ``static``:
elements in proportion to the threads), first-touch places it in that socket's memory, and the
socket's memory controller spreads it over its channels. The statistics of one channel of a socket
are :func:`hdeem_watch.dram.kernels.kernel_stats` of the socket's threads and elements with
``channels = channels_per_socket`` and XOR bank hashing (Haswell-EP controllers hash banks; without
it every thread's power-of-two chunk starts in the same bank and almost every access is a row
conflict). A socket without threads is an idle group: statistics with no commands.

The calibrator turns the groups into ONE calibration row against the node's total DRAM energy
(:func:`hdeem_watch.calibrate.rows.node_observation`).

Example:
    >>> NodeTopology().threads_per_socket(18)
    (12, 6)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from hdeem_watch.dram.memspec import MemSpec
from hdeem_watch.dram.stats import CommandStats, RankStats
from hdeem_watch.errors import InputError

#: Kernel names that move no DRAM traffic (idle and compute-only runs): their channels are modelled
#: as idle groups whatever the run's size.
NO_TRAFFIC_KERNELS = ("idle", "sleep", "compute", "none")


@dataclass(frozen=True)
class NodeTopology:
    """Sockets, cores and memory channels (one DIMM each) of a node.

    Attributes:
        sockets: CPU sockets.
        cores_per_socket: physical cores per socket (logical CPUs beyond ``sockets × cores`` are
            hyper-threads, placed the same way).
        channels_per_socket: memory channels (DIMMs) per socket.
    """

    sockets: int = 2
    cores_per_socket: int = 12
    channels_per_socket: int = 4

    def __post_init__(self) -> None:
        for name in ("sockets", "cores_per_socket", "channels_per_socket"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise InputError(f"topology.{name}: {value!r}; expected an integer >= 1")

    @property
    def channels(self) -> int:
        """Memory channels (DIMMs) of the node."""
        return self.sockets * self.channels_per_socket

    def threads_per_socket(self, threads: int) -> tuple[int, ...]:
        """Threads on each socket (logical CPU ``i`` on socket ``(i // cores_per_socket) % sockets``)."""
        n = max(0, int(threads))
        full, rest = divmod(n, self.cores_per_socket)
        counts = [0] * self.sockets
        for block in range(full):
            counts[block % self.sockets] += self.cores_per_socket
        if rest:
            counts[full % self.sockets] += rest
        return tuple(counts)

    def shares(self, threads: int) -> tuple[float, ...]:
        """Fraction of a run's traffic on each socket (proportional to its threads)."""
        counts = self.threads_per_socket(threads)
        total = sum(counts)
        return tuple(c / total if total else 0.0 for c in counts)


#: The modelled Haswell-EP node of DESIGN.md §5.
HASWELL_EP = NodeTopology()


def topology_for(dimms: int) -> NodeTopology:
    """The 2-socket, 12-core topology with ``dimms`` channels (1 socket if ``dimms`` is odd)."""
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


def node_run_stats(spec: MemSpec, kernel: str, elements: int, threads: int, repeat: int,
                   topology: NodeTopology = HASWELL_EP, *, xor_bank: bool = True,
                   max_requests: int | None = None) -> list[tuple[CommandStats, int]]:
    """Per socket (in order), the statistics of ONE of its channels and how many channels it has.

    Args:
        spec: memspec of one DIMM.
        kernel: kernel name (one of :data:`NO_TRAFFIC_KERNELS` = no traffic).
        elements: doubles per array (of the whole run).
        threads: threads of the run.
        repeat: passes.
        topology: the node.
        xor_bank: XOR bank hashing in the channels' address mapping.
        max_requests: prefix size of the kernel model (None = its default).

    Returns:
        ``[(stats, channels), ...]``, one entry per socket; a socket without traffic is an idle
        group (:func:`idle_channel_stats`).

    Raises:
        InputError: an unknown kernel or a bad size.
    """
    from hdeem_watch.dram.kernels import kernel_stats

    idle = idle_channel_stats(spec)
    counts = topology.threads_per_socket(threads)
    no_traffic = str(kernel).strip().lower() in NO_TRAFFIC_KERNELS or int(elements) <= 0 or int(repeat) <= 0
    groups: list[tuple[CommandStats, int]] = []
    for socket_threads in counts:
        n_elements = socket_elements(elements, threads, socket_threads)
        if no_traffic or socket_threads == 0 or n_elements <= 0:
            groups.append((idle, topology.channels_per_socket))
            continue
        options: dict[str, Any] = {"repeat": int(repeat), "channels": topology.channels_per_socket,
                                   "xor_bank": xor_bank}
        if max_requests:
            options["max_requests"] = int(max_requests)
        stats = kernel_stats(spec, kernel, n_elements, socket_threads, **options).stats
        groups.append((stats, topology.channels_per_socket))
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
