"""Opaque jobs on the simulated node: a hidden traffic mix that only the memory counters describe.

A run started without a kernel (``kernel = "job"``, :data:`JOB_KERNEL`) is an opaque job: the
daemon knows nothing of its traffic. The sim plays a hidden mix of phases, seeded by the node's seed
and the run id, and repeats it until the job is stopped:

- **stream**: a STREAM-like kernel (read, copy, scale, add, triad) with a random thread count,
  through the sim's own controller (:mod:`hdeem_watch.sim.traffic`: page placement, hashes,
  row hits) at the node's bandwidth for those threads;
- **random**: random accesses (row misses: an activation per request but a few percent), a random
  share of the socket's bandwidth and of writes, on the sockets the job's threads occupy;
- **idle**: no traffic (the ranks drop into precharge power-down, :func:`~hdeem_watch.sim.power.idle_rank`).

Each phase has per-DIMM hidden :class:`~hdeem_watch.dram.stats.CommandStats` and is priced like a
kernel run (:func:`~hdeem_watch.sim.power.split_columns` at each DIMM's hidden currents, plus
I/O per burst). A stopped job owes nothing: its traffic simply ends (unlike a kernel run, whose
whole traffic is booked by the stop).

Example:
    >>> from hdeem_watch.sim.currents import PartCurrents
    >>> from hdeem_watch.sim.plan import TruthNode
    >>> node = TruthNode(seed=1)
    >>> parts = PartCurrents(node.model.names, node.model.datasheet, 1)
    >>> job = job_plan(node, parts.currents(0.0), parts.temperature_c(0.0), "r7", 0, threads=12)
    >>> len(job.phases) == PHASES, job.cycle_ns > 0
    (True, True)
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from hdeem_watch.dram.stats import CommandStats
from hdeem_watch.sim.model import kernel_traffic_lines, modelled_line_rate
from hdeem_watch.sim.power import busy_rank, idle_rank, split_columns

if TYPE_CHECKING:
    from hdeem_watch.sim.plan import TruthNode

#: The kernel name of an opaque job (``run.start`` without a kernel).
JOB_KERNEL = "job"
#: Phases in one cycle of a job's hidden mix.
PHASES = 6
#: Phase durations (sim s), uniform in this range.
PHASE_S = (0.6, 3.0)
#: Kernels a stream phase may run.
STREAM_KERNELS = ("read", "copy", "scale", "add", "triad")
#: A socket's peak random-access bandwidth (B/s): row misses halve what streaming reaches.
RANDOM_SOCKET_BPS = 25e9
#: Row-hit rate of random accesses over a large footprint.
RANDOM_HIT_RATE = 0.04
#: "Never" on the sim's ns axis (a job's traffic runs until it is stopped).
OPEN_END_NS = 1 << 62


@dataclass(frozen=True)
class JobPhase:
    """One phase of a job's cycle.

    Attributes:
        kind: ``"stream:<kernel>/<threads>t"``, ``"random"`` or ``"idle"``.
        start_ns: offset within the cycle.
        duration_ns: its length.
        excess_w: per DIMM, power above idle during the phase (W).
        stats: per DIMM, the hidden statistics over the phase.
    """

    kind: str
    start_ns: int
    duration_ns: int
    excess_w: np.ndarray
    stats: tuple[CommandStats, ...]


@dataclass(frozen=True)
class JobPlan:
    """An opaque job's load: its phases repeated from ``t0_ns`` until the stop.

    Has the attributes of :class:`~hdeem_watch.sim.model.RunPlan` the sim's signal and time
    shell read (``t0_ns``, ``threads``, ``traffic_end_ns``, ``cpu_end_ns``, ``idle_w``).
    """

    run_id: str
    t0_ns: int
    phases: tuple[JobPhase, ...]
    idle_w: np.ndarray
    threads: tuple[int, ...]
    traffic_end_ns: int = OPEN_END_NS
    cpu_end_ns: int | None = None

    @property
    def cycle_ns(self) -> int:
        """Length of one cycle of the phases."""
        return sum(p.duration_ns for p in self.phases)

    @property
    def duration_ns(self) -> int:
        """Positive: the job has traffic (``RunPlan`` callers test ``duration_ns > 0``)."""
        return self.cycle_ns

    def phase_seconds(self, t_ns: np.ndarray | int) -> np.ndarray:
        """Seconds spent in each phase between ``t0_ns`` and ``t_ns`` (shape ``(..., phases)``)."""
        t = np.asarray(t_ns, dtype=np.float64)
        elapsed = np.clip(np.minimum(t, float(self.traffic_end_ns)) - self.t0_ns, 0.0, None)
        cycle = float(self.cycle_ns)
        full, rest = np.floor(elapsed / cycle), np.mod(elapsed, cycle)
        starts = np.array([p.start_ns for p in self.phases], dtype=np.float64)
        lengths = np.array([p.duration_ns for p in self.phases], dtype=np.float64)
        partial = np.clip(rest[..., None] - starts, 0.0, lengths)
        return np.asarray((full[..., None] * lengths + partial) * 1e-9)

    def excess_energy_j(self, t_ns: np.ndarray | int) -> np.ndarray:
        """Per DIMM, the excess energy (J) from ``t0_ns`` to ``t_ns`` (shape ``(..., dimms)``)."""
        excess = np.stack([p.excess_w for p in self.phases])  # phases × dimms
        return np.asarray(self.phase_seconds(t_ns) @ excess)

    def dram_w(self, dimms: list[int], t_end: np.ndarray, period: int) -> np.ndarray:
        """Mean excess power of ``dimms`` over each interval ``(t − period, t]``."""
        energy = self.excess_energy_j(t_end) - self.excess_energy_j(t_end - period)
        return np.asarray(energy[:, dimms].sum(axis=1) / (period * 1e-9))

    def stopped(self, t_ns: int) -> tuple[JobPlan, np.ndarray]:
        """The job stopped at ``t_ns``: its traffic ends there, nothing is owed."""
        end = max(self.t0_ns, int(t_ns))
        return replace(self, traffic_end_ns=min(self.traffic_end_ns, end), cpu_end_ns=end), np.zeros_like(self.idle_w)


def _rng(seed: int, run_id: str) -> np.random.Generator:
    return np.random.default_rng([int(seed), zlib.crc32(run_id.encode()), 17])


def _priced(node: TruthNode, currents: np.ndarray, idle_w: np.ndarray, stats: list[CommandStats | None],
            duration_s: float, temps_c: np.ndarray) -> tuple[np.ndarray, tuple[CommandStats, ...]]:
    """Per DIMM, the excess power of ``stats`` over ``duration_s`` and the stats (idle ones filled in)."""
    spec, physics = node.spec, node.physics
    excess = np.zeros(len(stats))
    filled = []
    for d, dimm_stats in enumerate(stats):
        if dimm_stats is None:
            idle = idle_rank(spec, duration_s, float(temps_c[d]), physics.hot_c)
            filled.append(CommandStats(ranks=(idle,) * int(spec.nbr_of_ranks)))
            continue
        bg_cols, cmd_cols, const = split_columns(spec, dimm_stats)
        io = physics.io_read_j * dimm_stats.total("rd") + physics.io_write_j * dimm_stats.total("wr")
        energy = float(currents[d] @ (bg_cols + cmd_cols)) + const + io
        excess[d] = energy / duration_s - float(idle_w[d])
        filled.append(dimm_stats)
    return excess, tuple(filled)


def _random_stats(node: TruthNode, rng: np.random.Generator, threads: int, duration_s: float,
                  temps_c: np.ndarray) -> list[CommandStats | None]:
    layout, spec = node.layout, node.spec
    share, writes = float(rng.uniform(0.2, 0.9)), float(rng.uniform(0.0, 0.5))
    out: list[CommandStats | None] = [None] * len(layout.dimm_names)
    ranks = int(spec.nbr_of_ranks)
    for socket, n_threads in enumerate(layout.topology.threads_per_socket(threads)):
        if n_threads <= 0:
            continue
        dimms = [d for d, s in enumerate(layout.dimm_socket) if s == socket]
        lines = RANDOM_SOCKET_BPS * share * min(1.0, n_threads / 8) / 64 * duration_s / len(dimms)
        per_rank = lines / ranks
        for d in dimms:
            out[d] = CommandStats(ranks=tuple(
                busy_rank(spec, duration_s, float(temps_c[d]), per_rank * (1 - writes), per_rank * writes,
                          per_rank * (1 - RANDOM_HIT_RATE), lines, node.physics) for _ in range(ranks)))
    return out


def _stream_stats(node: TruthNode, kernel: str, threads: int, duration_s: float,
                  temps_c: np.ndarray) -> list[CommandStats | None]:
    elements = 1 << 24
    traffic = kernel_traffic_lines(kernel, elements)
    rate = modelled_line_rate(kernel, threads, elements, node.layout)
    if traffic is None or rate <= 0:
        return [None] * len(node.layout.dimm_names)
    repeat = duration_s * rate / float(sum(traffic))
    return node.dimm_stats(kernel, elements, threads, repeat, duration_s, temps_c)  # type: ignore[arg-type]


def job_plan(node: TruthNode, currents: np.ndarray, temps_c: np.ndarray, run_id: str, t0_ns: int, *,
             threads: int) -> JobPlan:
    """The hidden mix of an opaque job starting at ``t0_ns`` (deterministic for a seed and run id).

    Args:
        node: the sim's truth generator (layout, memspec, physics, seed).
        currents: per DIMM hidden currents at the start.
        temps_c: per DIMM temperatures at the start.
        run_id: the daemon's run id (seeds the mix with the node's seed).
        t0_ns: start (sim ns).
        threads: the job's threads (its CPU load; stream phases use up to that many).
    """
    rng = _rng(node.seed, run_id)
    idle_w = node.idle_power_w(currents, temps_c)
    cores = node.layout.topology.cores_per_socket * node.layout.sockets
    most = max(1, min(int(threads), cores))
    phases, start = [], 0
    for _ in range(PHASES):
        duration_s = float(rng.uniform(*PHASE_S))
        draw = float(rng.uniform())
        if draw < 0.45:
            kernel = STREAM_KERNELS[int(rng.integers(len(STREAM_KERNELS)))]
            n = int(rng.integers(1, most + 1))
            kind, stats = f"stream:{kernel}/{n}t", _stream_stats(node, kernel, n, duration_s, temps_c)
        elif draw < 0.8:
            kind, stats = "random", _random_stats(node, rng, most, duration_s, temps_c)
        else:
            kind, stats = "idle", [None] * len(node.layout.dimm_names)
        excess, filled = _priced(node, currents, idle_w, stats, duration_s, temps_c)
        d_ns = round(duration_s * 1e9)
        phases.append(JobPhase(kind, start, d_ns, excess, filled))
        start += d_ns
    return JobPlan(run_id, int(t0_ns), tuple(phases), idle_w, node.layout.topology.threads_per_socket(threads))
