"""The daemon's model of the simulated node: bandwidth, the DRAM model, and the model's view of a run.

The sim's truth does NOT come from here (:mod:`hdeem_watch.sim.plan` is its own generator);
this module holds what the sim shares with the daemon's model — the node's bandwidth (how long a
run's traffic lasts, which the demo's schedule uses to hold runs) and the DRAM model (memspec,
energy columns) — and :func:`plan_run` / :func:`run_truth_energy_j` / :func:`effective_currents`,
the model's view of a run at given currents, kept to measure how far the truth is from it.

The modelled node is a 2-socket Haswell-EP (2 × 12 cores, logical CPUs 0–11 on socket 0, 12–23 on
socket 1, 24–35 and 36–47 their hyper-threads) with 8 DIMMs of the Samsung M393A1G43DB0-CPB, one
per memory channel, 4 channels per socket — by default; any node with one DIMM per channel can be
modelled instead (:class:`~hdeem_watch.sim.layout.SimLayout`, e.g. from a detected
:class:`~hdeem_watch.node.description.NodeDescription`). HDEEM's DIMM-pair sensors: DDR_AB = DIMMs A, B and
DDR_CD = C, D on socket 0; DDR_EF = E, F and DDR_GH = G, H on socket 1.

Traffic split (:func:`hdeem_watch.dram.node.node_run_stats`, the same function the daemon's
calibration row uses): threads fill socket 0 first; each socket's threads move their share of the
arrays through that socket's 4 channels; a socket without threads stays idle.

Bandwidth (:func:`modelled_line_rate`): each thread streams ``PER_THREAD_BPS`` = 7 GB/s, a socket
saturates at ``SOCKET_MAX_BPS`` = 58 GB/s, joined by a smooth minimum ``(x⁻⁴ + M⁻⁴)^(-1/4)``;
kernels that write lose ``WRITE_FACTOR`` = 12 % to read/write turnarounds; and a socket never moves
more than its channels can serve in the controller model (channels / (cycles per line × tCK)). The
run ends when the socket with the most work per bandwidth is done.

The model's energy of a run (:func:`plan_run`): per DIMM, the statistics of its socket's group stretched to the
modelled duration exactly as the calibrator stretches them to a measured window
(:func:`hdeem_watch.calibrate.rows.stretch_stats`), and the energy is
``energy_columns(spec, stats) @ truth_currents + constant`` (identical to ``core_energy``). On top
comes I/O energy per line (VDDQ, termination; not in the core model, collinear with the IDD4R/IDD4W
columns), see :func:`effective_currents`.

Example:
    >>> round(modelled_line_rate("read", 1) * 64 / 1e9, 1)
    7.0
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from hdeem_watch.dram.node import lines_of, node_capacity_lines_s, node_run_stats
from hdeem_watch.dram.stats import CommandStats, RankStats, refresh_interval
from hdeem_watch.sim.currents import PartCurrents
from hdeem_watch.sim.layout import TAURUS, SimLayout

#: The default (Taurus) layout's DIMM names, in channel order (A..H), and the HDEEM pair channel
#: and socket of each; other layouts: :class:`~hdeem_watch.sim.layout.SimLayout`.
DIMMS = TAURUS.dimm_names
DIMM_PAIR = TAURUS.dimm_sensor
DIMM_SOCKET = TAURUS.dimm_socket
TOPOLOGY = TAURUS.topology
CORES_PER_SOCKET = TOPOLOGY.cores_per_socket
SOCKETS = TOPOLOGY.sockets
CHANNELS_PER_SOCKET = TOPOLOGY.channels_per_socket
MEMSPEC_PRESET = "samsung-m393a1g43db0-cpb"

PER_THREAD_BPS = 7.0e9
#: Per-thread demand of kernels that cannot stream: random reads keep fewer misses in flight (no
#: prefetcher), a dependent pointer chase one (a line per ~90 ns of load-to-use latency).
KERNEL_THREAD_BPS = {"gups": 2.5e9, "chase": 0.7e9}
SOCKET_MAX_BPS = 58.0e9
WRITE_FACTOR = 0.88
LINE_BYTES = 64
#: Array size (doubles) at which :func:`modelled_line_rate` takes the controller's capacity when
#: the caller gives none (the demo's size; cycles per line hardly depend on it).
REFERENCE_ELEMENTS = 1 << 24
#: The currents the daemon's fit calibrates (DESIGN.md §4 default), for :func:`effective_currents`.
CALIBRATED = ("idd0", "idd2n", "idd3n", "idd4r", "idd4w")


def threads_per_socket(threads: int) -> tuple[int, int]:
    """Threads on socket 0 and 1: logical CPU i sits on socket ``(i // 12) % 2`` (fill socket 0 first)."""
    s0, s1 = TOPOLOGY.threads_per_socket(threads)
    return s0, s1


def socket_shares(threads: int) -> tuple[float, float]:
    """Fraction of a run's DRAM traffic on socket 0 and 1 (proportional to the threads there)."""
    s0, s1 = TOPOLOGY.shares(threads)
    return s0, s1


def _socket_bps(n_threads: int, kernel: str = "") -> float:
    if n_threads <= 0:
        return 0.0
    x = n_threads * KERNEL_THREAD_BPS.get(kernel, PER_THREAD_BPS)
    return float((x ** -4 + SOCKET_MAX_BPS ** -4) ** -0.25)


def kernel_traffic_lines(kernel: str, elements: int) -> tuple[int, int] | None:
    """Lines (read, written) of one pass, or ``None`` if ``kernel`` moves no DRAM traffic."""
    from hdeem_watch.dram.kernels import kernel_traffic

    try:
        traffic = kernel_traffic(kernel, int(elements))
    except ValueError:  # InputError: unknown kernel = compute-only
        return None
    return int(traffic.lines_read), int(traffic.lines_written)


def line_rate_of(model: DramModel, kernel: str, threads: int, groups: list[tuple[CommandStats, int]]) -> float:
    """Lines/s of a run whose per-socket statistics are ``groups`` (0.0 without traffic).

    Each socket moves ``min(threads' demand, its channels' capacity)``; the run's rate is set by the
    socket that needs longest for its share.
    """
    traffic = kernel_traffic_lines(kernel, 8)
    if traffic is None or threads <= 0:
        return 0.0
    counts = model.layout.topology.threads_per_socket(threads)
    lines = [lines_of(stats) * n for stats, n in groups]
    total = sum(lines)
    if total <= 0:
        return 0.0
    capacity = node_capacity_lines_s(model.spec, groups)
    rate = math.inf
    for n_threads, share_lines, cap in zip(counts, lines, capacity):
        if share_lines <= 0:
            continue
        demand = _socket_bps(n_threads, kernel) * (WRITE_FACTOR if traffic[1] else 1.0) / LINE_BYTES
        socket_rate = min(demand, cap) if cap > 0 else demand
        rate = min(rate, socket_rate * total / share_lines)
    return 0.0 if rate == math.inf else float(rate)


def modelled_line_rate(kernel: str, threads: int, elements: int = REFERENCE_ELEMENTS,
                       layout: SimLayout = TAURUS) -> float:
    """64-byte lines per second the modelled node moves for ``kernel`` with ``threads`` threads.

    0.0 for a kernel without DRAM traffic (compute-only / idle). ``elements`` sets the array size
    whose controller model caps the rate (cycles per line hardly depend on it).
    """
    if kernel_traffic_lines(kernel, 8) is None or threads <= 0:
        return 0.0
    return _cached_rate(str(kernel), int(threads), int(elements), layout)


@functools.lru_cache(maxsize=512)
def _cached_rate(kernel: str, threads: int, elements: int, layout: SimLayout = TAURUS) -> float:
    model = model_for(layout)
    return line_rate_of(model, kernel, threads, model.node_stats(kernel, elements, threads, 1))


def sim_memspec(name: str) -> Any:
    """The memspec of the sim's DIMMs: a preset by name, or a ``.json`` file of this package
    (:data:`~hdeem_watch.sim.layout.DDR5_MEMSPEC`, the DDR5 node's)."""
    from pathlib import Path

    from hdeem_watch.dram.memspec import preset

    if name.endswith(".json"):
        from hdeem_watch.dram.memspec_ddr5 import load_memspec_ddr5

        return load_memspec_ddr5(Path(__file__).with_name(name))
    return preset(name)


def memspec_setting(layout: SimLayout = TAURUS) -> str:
    """The layout's memspec as the daemon's ``memspec`` setting names one: a preset name, or the
    absolute path of this package's memspec file (the DDR5 node's ``ddr5_node.json``).

    Example:
        >>> memspec_setting(), memspec_setting(SimLayout.per_socket(1, 4, 2))
        ('samsung-m393a1g43db0-cpb', 'samsung-m393a1g43db0-cpb')
    """
    from pathlib import Path

    if layout.memspec.endswith(".json"):
        return str(Path(__file__).with_name(layout.memspec))
    return layout.memspec


class DramModel:
    """The DRAM model (memspec, energy columns, node statistics) of the sim's DIMMs.

    Args:
        layout: the node's sockets, cores and channels (default: the Taurus Haswell-EP node).
    """

    backend = "dram"

    def __init__(self, layout: SimLayout = TAURUS) -> None:
        from hdeem_watch.dram.linear import model_current_names

        self.layout = layout
        self.spec: Any = sim_memspec(layout.memspec)
        self.names: tuple[str, ...] = model_current_names(self.spec)
        self.datasheet = np.array([float(self.spec.currents.get(n, 0.0)) for n in self.names])
        self.tck_s = float(self.spec.tck_s)
        self._node_stats = functools.lru_cache(maxsize=256)(self._compute_node_stats)
        self._idle_per_s: tuple[np.ndarray, float] | None = None

    def _compute_node_stats(self, kernel: str, elements: int, threads: int, repeat: int) -> tuple[tuple[CommandStats, int], ...]:
        return tuple(node_run_stats(self.channel_spec, kernel, elements, threads, repeat, self.layout.topology))

    @property
    def channel_spec(self) -> Any:
        """The memspec of one of the layout's channels as the controller model spells it: DDR4's as it
        is, a DDR5 sub-channel (:func:`~hdeem_watch.dram.ddr5_channel.subchannel_spec`) for DDR5,
        whose layouts count sub-channels as channels."""
        from hdeem_watch.dram.ddr5_channel import controller_spec

        return controller_spec(self.spec)

    def node_stats(self, kernel: str, elements: int, threads: int, repeat: int) -> list[tuple[CommandStats, int]]:
        """``node_run_stats(spec, ..., layout.topology)`` (cached): per socket, one channel's stats and count."""
        if kernel_traffic_lines(kernel, 8) is None:
            kernel = "idle"
        return list(self._node_stats(str(kernel), int(elements), int(threads), int(repeat)))

    def idle_stats(self, window_s: float) -> CommandStats:
        """No commands: all banks precharged, a refresh every REFI — the form the calibrator gives an
        idle run (``calibrate.rows.stretch_stats`` of empty statistics), so idle energy matches it."""
        total = window_s / self.tck_s
        refi = refresh_interval(self.spec)
        rank = RankStats(ref=total / refi if refi > 0 else 0.0, cycles_total=total, cycles_pre=total)
        return CommandStats(ranks=(rank,) * self.spec.nbr_of_ranks)

    def idle_columns_per_s(self) -> tuple[np.ndarray, float]:
        """The model's idle DIMM per second (:meth:`idle_stats` of 1 s, :meth:`linear`), computed once."""
        if self._idle_per_s is None:
            self._idle_per_s = self.linear(self.idle_stats(1.0))
        return self._idle_per_s

    def stretched(self, stats: CommandStats, window_s: float) -> CommandStats:
        """``stats`` stretched to ``window_s`` exactly as the calibrator does."""
        from hdeem_watch.dram.stats import stretch_stats

        return stretch_stats(self.spec, stats, window_s)

    def linear(self, stats: CommandStats) -> tuple[np.ndarray, float]:
        """``energy_columns(spec, stats)`` as (columns, constant_j)."""
        from hdeem_watch.dram.linear import linear_energy

        lin = linear_energy(self.spec, stats)
        return np.asarray(lin.columns, dtype=float), float(lin.constant_j)

    def burst_j_per_a(self) -> float:
        """Joules per ampere of one read or write burst of one rank (the IDD4R/IDD4W column per burst)."""
        return float(self.spec.vdd * self.tck_s * self.spec.nbr_of_devices * self.spec.burst_cycles)

    def standby_w_per_a(self) -> float:
        """Watts per ampere of a current shift in every state of every rank of one DIMM."""
        return float(self.spec.vdd * self.spec.nbr_of_devices * self.spec.nbr_of_ranks)


Model = DramModel


@functools.lru_cache(maxsize=8)
def model_for(layout: SimLayout) -> DramModel:
    """The shared DRAM model of a layout (built once per layout)."""
    return DramModel(layout)


def default_model() -> DramModel:
    """The shared DRAM model of the default (Taurus) node."""
    return model_for(TAURUS)


def load_model(layout: SimLayout = TAURUS) -> Model:
    """The DRAM model of the sim's DIMMs (shared, built once per layout)."""
    return model_for(layout)


def effective_currents(model: Model, currents: np.ndarray, io_j_per_line: float, offsets_w: float = 0.0,
                       calibrated: tuple[str, ...] = CALIBRATED) -> np.ndarray:
    """What a node-level fit of the ``calibrated`` currents can recover from the sim (A per device).

    The fit holds every other current at its datasheet value, and the sim's signal has parts the
    core model cannot tell apart from the calibrated currents; each maps exactly onto them:

    - I/O energy per line is a fixed energy per read or write burst: IDD4R and IDD4W +
      ``io_j_per_line / (vdd · tCK · devices · burst cycles)``.
    - A constant power ``P`` per DIMM (the DIMM-pair sensor offsets, ``offsets_w`` for all pairs,
      and the refresh current's deviation from its datasheet value, ``(IDD5B − IDD5B_ds) · vdd ·
      devices · ranks · tRFC/tREFI``) shifts every calibrated VDD current by
      ``P / (vdd · devices · ranks · (1 − tRFC/tREFI))`` (their columns sum to the window minus the
      refresh cycles).
    - IPP0's column is IDD0's × vpp/vdd: IDD0 + (IPP0 − IPP0_ds) · vpp/vdd.

    Exact for statistics without power-down and with a refresh every tREFI (the sim's node).
    The uncalibrated currents are returned at their datasheet values (where the fit holds them).

    Args:
        model: the DRAM model.
        currents: core truth, ``(..., names)`` (e.g. 8 DIMMs × names).
        io_j_per_line: the sim's I/O energy per line (J).
        offsets_w: sum of the DIMM-pair channels' sensor offsets (W).
        calibrated: the currents the fit calibrates.
    """
    spec = model.spec
    names = list(model.names)
    truth = np.asarray(currents, dtype=float)
    out = np.broadcast_to(model.datasheet, truth.shape).copy()
    idx = [names.index(n) for n in calibrated if n in names]
    out[..., idx] = truth[..., idx]
    f_ref = float(spec.trfc) / refresh_interval(spec)
    per_dimm_w = offsets_w / len(model.layout.dimm_names)
    i5b = names.index("idd5b")
    refresh_w = (truth[..., i5b] - model.datasheet[i5b]) * model.standby_w_per_a() * f_ref
    shift = (per_dimm_w + refresh_w) / (model.standby_w_per_a() * (1.0 - f_ref))
    for j in idx:
        if names[j].startswith("idd"):
            out[..., j] += shift
    io_a = io_j_per_line / model.burst_j_per_a()
    for name in ("idd4r", "idd4w"):
        if name in calibrated:
            out[..., names.index(name)] += io_a
    if "idd0" in calibrated:
        ipp0 = names.index("ipp0")
        out[..., names.index("idd0")] += (truth[..., ipp0] - model.datasheet[ipp0]) * float(spec.vpp) / float(spec.vdd)
    return out


#: The hidden per-DIMM currents (the name the model side has always used).
TruthModel = PartCurrents


@dataclass(frozen=True)
class RunPlan:
    """The DRAM and CPU load of one announced run, in sim time.

    Attributes:
        run_id: the daemon's run id.
        t0_ns: start (sim ns since open).
        duration_ns: modelled traffic duration D (0 = no traffic).
        bg_w: per DIMM, the run's background power (W) while traffic flows.
        dyn_j: per DIMM, command (ACT/PRE/RD/WR) energy of the whole run (J).
        io_j: per DIMM, I/O energy of the whole run (J; not modelled by the calibrator).
        idle_w: per DIMM, idle power at the start (W) — the run adds ``bg_w + (dyn_j + io_j)/D − idle_w``.
        threads: busy threads per socket.
        traffic_end_ns: end of traffic (t0 + D, or the stop if earlier).
        cpu_end_ns: end of CPU load (the stop; ``None`` while running).
        stats: per DIMM, the hidden statistics of the whole traffic (``None``: no traffic on it;
            empty: not kept), from which the sim's memory-controller counters are made.
    """

    run_id: str
    t0_ns: int
    duration_ns: int
    bg_w: np.ndarray
    dyn_j: np.ndarray
    io_j: np.ndarray
    idle_w: np.ndarray
    threads: tuple[int, ...]
    traffic_end_ns: int
    cpu_end_ns: int | None = None
    stats: tuple[CommandStats | None, ...] = ()

    @property
    def excess_w(self) -> np.ndarray:
        """Per DIMM, power above idle while traffic flows."""
        if self.duration_ns <= 0:
            return np.zeros_like(self.bg_w)
        return self.bg_w + (self.dyn_j + self.io_j) / (self.duration_ns * 1e-9) - self.idle_w

    def stopped(self, t_ns: int) -> tuple[RunPlan, np.ndarray]:
        """The plan stopped at ``t_ns`` and the per-DIMM energy (J) still owed (unfinished traffic)."""
        owed = np.zeros_like(self.dyn_j)
        end = self.traffic_end_ns
        if self.duration_ns > 0 and t_ns < self.traffic_end_ns:
            done = max(0, t_ns - self.t0_ns) / self.duration_ns
            owed = (self.dyn_j + self.io_j) * (1.0 - done)
            end = max(self.t0_ns, t_ns)
        return replace(self, traffic_end_ns=end, cpu_end_ns=max(self.t0_ns, t_ns)), owed


def idle_power_w(model: Model, currents: np.ndarray) -> np.ndarray:
    """Idle power (W) per DIMM for per-DIMM ``currents`` (DIMMs × names)."""
    cols, const = model.idle_columns_per_s()
    return np.asarray(currents @ cols + const, dtype=float)


def plan_run(model: Model, currents: np.ndarray, run_id: str, t0_ns: int, kernel: str, elements: int,
             threads: int, repeat: int, io_j_per_line: float) -> RunPlan:
    """The energy plan of a run starting at ``t0_ns`` with the true ``currents`` (DIMMs × names) then."""
    idle = idle_power_w(model, currents)
    layout = model.layout
    tps = layout.topology.threads_per_socket(threads)
    traffic = kernel_traffic_lines(kernel, elements)
    zeros = np.zeros(len(layout.dimm_names))
    if traffic is None or repeat <= 0 or sum(traffic) == 0 or threads <= 0:
        return RunPlan(run_id, t0_ns, 0, zeros, zeros, zeros, idle, tps, t0_ns)
    groups = model.node_stats(kernel, elements, threads, repeat)
    rate = line_rate_of(model, kernel, threads, groups)
    if rate <= 0:
        return RunPlan(run_id, t0_ns, 0, zeros, zeros, zeros, idle, tps, t0_ns)
    duration_s = float(sum(traffic) * repeat) / rate
    bg, dyn, io = zeros.copy(), zeros.copy(), zeros.copy()
    for socket, (stats, _channels) in enumerate(groups):
        c1, k1 = model.linear(model.stretched(stats, duration_s))
        c2, k2 = model.linear(model.stretched(stats, 2 * duration_s))
        for d, dimm_socket in enumerate(layout.dimm_socket):
            if dimm_socket != socket:
                continue
            e1 = float(currents[d] @ c1 + k1)
            e2 = float(currents[d] @ c2 + k2)
            bg[d] = (e2 - e1) / duration_s
            dyn[d] = e1 - bg[d] * duration_s
            io[d] = io_j_per_line * lines_of(stats)
    d_ns = max(1, round(duration_s * 1e9))
    return RunPlan(run_id, t0_ns, d_ns, bg, dyn, io, idle, tps, t0_ns + d_ns)


def run_truth_energy_j(model: Model, currents: np.ndarray, kernel: str, elements: int, threads: int,
                       repeat: int, window_s: float) -> float:
    """Core energy (J) of the node's DIMMs for a run evaluated over ``window_s`` (no I/O, no offsets)."""
    groups = model.node_stats(kernel, elements, threads, repeat)
    total = 0.0
    for socket, (stats, _channels) in enumerate(groups):
        cols, const = model.linear(model.stretched(stats, window_s))
        for d, dimm_socket in enumerate(model.layout.dimm_socket):
            if dimm_socket == socket:
                total += float(currents[d] @ cols + const)
    return total
