"""The pure model behind the simulated node: bandwidth, hidden true currents, run energy plans.

The modelled node is a 2-socket Haswell-EP (2 × 12 cores, logical CPUs 0–11 on socket 0, 12–23 on
socket 1, 24–35 and 36–47 their hyper-threads) with 8 DIMMs of the Samsung M393A1G43DB0-CPB, one
per memory channel, 4 channels per socket. HDEEM's DIMM-pair sensors: DDR_AB = DIMMs A, B and
DDR_CD = C, D on socket 0; DDR_EF = E, F and DDR_GH = G, H on socket 1.

Bandwidth (:func:`modelled_line_rate`): each thread streams ``PER_THREAD_BPS`` = 7 GB/s, a socket
saturates at ``SOCKET_MAX_BPS`` = 58 GB/s (4 × DDR4-2133 channels = 68 GB/s peak; STREAM reaches
~55–60), joined by a smooth minimum ``(x⁻⁴ + M⁻⁴)^(-1/4)`` (12 threads → 55 GB/s); kernels that
write lose ``WRITE_FACTOR`` = 12 % to read/write turnarounds. Threads fill socket 0 first.

Energy of a run (:func:`plan_run`): the command counts are those the daemon's calibrator uses —
``kernel_stats(spec, kernel, elements, threads, repeat=repeat, channels=8)`` — the counts of a
channel scaled by the traffic share of its socket (×2 for socket 0's channels with ≤ 12 threads),
the background residency and refresh stretched to the modelled duration (a DIMM whose socket gets
no traffic stays idle: precharge standby and refresh), and
the energy is ``energy_columns(spec, stats) @ truth_currents + constant`` per DIMM (identical to
``core_energy`` by the model's linearity). Until the DRAM model modules exist, a private classic
DRAMPower model stands in (:class:`FallbackModel`).

Example:
    >>> round(modelled_line_rate("read", 12) * 64 / 1e9, 1)
    55.1
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from hdeem_watch.dram.stats import CommandStats, RankStats

#: DIMM names, in channel order (A..H), and the HDEEM pair channel and socket of each.
DIMMS = ("A", "B", "C", "D", "E", "F", "G", "H")
DIMM_PAIR = ("DDR_AB", "DDR_AB", "DDR_CD", "DDR_CD", "DDR_EF", "DDR_EF", "DDR_GH", "DDR_GH")
DIMM_SOCKET = (0, 0, 0, 0, 1, 1, 1, 1)
CORES_PER_SOCKET = 12
SOCKETS = 2
CHANNELS_PER_SOCKET = 4
MEMSPEC_PRESET = "samsung-m393a1g43db0-cpb"

PER_THREAD_BPS = 7.0e9
SOCKET_MAX_BPS = 58.0e9
WRITE_FACTOR = 0.88
LINE_BYTES = 64

#: Lines read/written per element-line of one pass (write-allocate included), used only by the
#: fallback when ``hdeem_watch.dram.kernels`` is not importable.
_FALLBACK_TRAFFIC = {
    "read": (1, 0), "assign": (1, 1), "scale": (2, 1), "add": (3, 1), "addition": (3, 1),
    "triad": (2, 1), "copy": (2, 1), "selfscale": (1, 1),
}
#: Currents whose temperature coefficient is the larger (standby, refresh, power-down).
_BACKGROUND = ("idd2n", "idd3n", "idd2p", "idd3p", "idd6n", "idd5b", "ipp2n", "ipp3n", "ipp5b", "ipp6n")


def threads_per_socket(threads: int) -> tuple[int, int]:
    """Threads on socket 0 and 1: logical CPU i sits on socket ``(i // 12) % 2`` (fill socket 0 first)."""
    n = max(0, int(threads))
    counts = [0, 0]
    for i in range(n):
        counts[(i // CORES_PER_SOCKET) % SOCKETS] += 1
    return counts[0], counts[1]


def socket_shares(threads: int) -> tuple[float, float]:
    """Fraction of a run's DRAM traffic on socket 0 and 1 (proportional to the threads there)."""
    s0, s1 = threads_per_socket(threads)
    total = s0 + s1
    return (s0 / total, s1 / total) if total else (0.0, 0.0)


def _socket_bps(n_threads: int) -> float:
    if n_threads <= 0:
        return 0.0
    x = n_threads * PER_THREAD_BPS
    return float((x ** -4 + SOCKET_MAX_BPS ** -4) ** -0.25)


def kernel_traffic_lines(kernel: str, elements: int) -> tuple[int, int] | None:
    """Lines (read, written) of one pass, or ``None`` if ``kernel`` moves no DRAM traffic."""
    try:
        from hdeem_watch.dram.kernels import kernel_traffic
    except ImportError:
        key = kernel.strip().lower()
        if key not in _FALLBACK_TRAFFIC:
            return None
        r, w = _FALLBACK_TRAFFIC[key]
        lines = -(-int(elements) // 8)
        return r * lines, w * lines
    try:
        traffic = kernel_traffic(kernel, int(elements))
    except ValueError:  # InputError: unknown kernel = compute-only
        return None
    return int(traffic.lines_read), int(traffic.lines_written)


def modelled_line_rate(kernel: str, threads: int) -> float:
    """64-byte lines per second the modelled node moves for ``kernel`` with ``threads`` threads.

    0.0 for a kernel without DRAM traffic (compute-only / idle).
    """
    traffic = kernel_traffic_lines(kernel, 8)
    if traffic is None or threads <= 0:
        return 0.0
    s0, s1 = threads_per_socket(threads)
    bps = _socket_bps(s0) + _socket_bps(s1)
    if traffic[1]:
        bps *= WRITE_FACTOR
    return bps / LINE_BYTES


def stretch_stats(stats: CommandStats, command_scale: float, window_s: float, tck_s: float) -> CommandStats:
    """Commands × ``command_scale``; background residency and refresh stretched to ``window_s``.

    The state fractions (active, precharged, power-down, self-refresh) of the model are kept, the
    window becomes ``window_s``, refreshes and bank-active cycles scale with the window.
    """
    target = window_s / tck_s
    ranks = []
    for r in stats.ranks:
        f = target / r.cycles_total if r.cycles_total > 0 else 0.0
        ranks.append(
            RankStats(
                act=r.act * command_scale, pre=r.pre * command_scale, rd=r.rd * command_scale,
                wr=r.wr * command_scale, rda=r.rda * command_scale, wra=r.wra * command_scale,
                ref=r.ref * f, cycles_total=target, cycles_act=r.cycles_act * f,
                cycles_pre=r.cycles_pre * f, cycles_pdna=r.cycles_pdna * f, cycles_pdnp=r.cycles_pdnp * f,
                cycles_sref=r.cycles_sref * f, bank_active_cycles=r.bank_active_cycles * f,
            )
        )
    return CommandStats(ranks=tuple(ranks))


@dataclass
class FallbackModel:
    """Classic DRAMPower DDR4 model (ρ = 1, Iβ = I0) for one 2-rank × 9-device DIMM.

    Used only until ``hdeem_watch.dram.memspec``/``energy``/``kernels`` can be imported. Datasheet
    currents are the DDR4-2133 4 Gb x8 mid-point of the reference memspec (per device, A).
    """

    backend: str = "fallback"
    names: tuple[str, ...] = ("idd0", "idd2n", "idd3n", "idd4r", "idd4w", "idd5b", "idd2p", "idd3p", "idd6n")
    datasheet: np.ndarray = field(
        default_factory=lambda: np.array([0.0585, 0.036, 0.04175, 0.171, 0.151875, 0.118, 0.017, 0.0225, 0.02025])
    )
    tck_s: float = 0.9375e-9
    vdd: float = 1.2
    devices: int = 9
    ranks: int = 2
    ras: int = 36
    rp: int = 15
    rfc: int = 278
    refi: int = 8320
    burst_cycles: int = 4

    def kernel_stats8(self, kernel: str, elements: int, threads: int, repeat: int) -> CommandStats:
        """Stats of one of 8 channels (a crude stand-in: 1 ACT per 16 lines, 60 % bus use)."""
        r_lines, w_lines = kernel_traffic_lines(kernel, elements) or (0, 0)
        rd = r_lines * repeat / 8 / self.ranks
        wr = w_lines * repeat / 8 / self.ranks
        act = (rd + wr) / 16
        total = max(1.0, (rd + wr) * self.ranks * self.burst_cycles / 0.6)
        rank = RankStats(act=act, pre=act, rd=rd, wr=wr, ref=total / self.refi, cycles_total=total,
                         cycles_act=0.9 * total, cycles_pre=0.1 * total, bank_active_cycles=0.9 * total * 4)
        return CommandStats(ranks=(rank,) * self.ranks)

    def idle_stats(self, window_s: float) -> CommandStats:
        """No commands: all banks precharged, a refresh every REFI (the calibrator's idle row)."""
        total = window_s / self.tck_s
        rank = RankStats(ref=total / self.refi, cycles_total=total, cycles_pre=total)
        return CommandStats(ranks=(rank,) * self.ranks)

    def linear(self, stats: CommandStats) -> tuple[np.ndarray, float]:
        """Columns (J/A, one per name) and constant (J) of ``stats``."""
        k = self.vdd * self.tck_s * self.devices
        cols = np.zeros(len(self.names))
        b = self.burst_cycles
        for r in stats.ranks:
            a, p, nr, nw, f = r.act, r.pre, r.rd + r.rda, r.wr + r.wra, r.ref
            cols += k * np.array([
                (self.ras + self.rp) * a, r.cycles_pre - self.rp * p,
                r.cycles_act - self.ras * a - b * (nr + nw) - self.rfc * f,
                b * nr, b * nw, self.rfc * f, r.cycles_pdnp, r.cycles_pdna, r.cycles_sref,
            ])
        return cols, 0.0


class DramModel:
    """The real DRAM model (A's memspec/energy, B's kernels) behind the fallback's interface."""

    backend = "dram"

    def __init__(self) -> None:
        from hdeem_watch.dram.energy import CURRENT_NAMES
        from hdeem_watch.dram.memspec import preset

        self.spec: Any = preset(MEMSPEC_PRESET)
        self.names: tuple[str, ...] = tuple(CURRENT_NAMES)
        self.datasheet = np.array([float(self.spec.currents.get(n, 0.0)) for n in self.names])
        self.tck_s = float(self.spec.tck_s)
        self._cache: dict[tuple[str, int, int, int], CommandStats] = {}

    def kernel_stats8(self, kernel: str, elements: int, threads: int, repeat: int) -> CommandStats:
        """``kernel_stats(spec, ..., channels=8).stats`` (cached)."""
        from hdeem_watch.dram.kernels import kernel_stats

        key = (kernel, int(elements), int(threads), int(repeat))
        if key not in self._cache:
            self._cache[key] = kernel_stats(self.spec, kernel, int(elements), int(threads),
                                            repeat=int(repeat), channels=8).stats
        return self._cache[key]

    def idle_stats(self, window_s: float) -> CommandStats:
        """No commands: all banks precharged, a refresh every REFI — the form the calibrator gives an
        idle run (``calibrate.rows.stretch_stats`` of empty statistics), so idle energy matches it."""
        total = window_s / self.tck_s
        rank = RankStats(ref=total / float(self.spec.timings["REFI"]), cycles_total=total, cycles_pre=total)
        return CommandStats(ranks=(rank,) * self.spec.nbr_of_ranks)

    def linear(self, stats: CommandStats) -> tuple[np.ndarray, float]:
        """``energy_columns(spec, stats)`` as (columns, constant_j)."""
        from hdeem_watch.dram.energy import energy_columns

        lin = energy_columns(self.spec, stats)
        return np.asarray(lin.columns, dtype=float), float(lin.constant_j)


Model = DramModel | FallbackModel


def load_model() -> Model:
    """The real DRAM model if its modules import and work, else the private fallback.

    A smoke test (a tiny kernel through ``kernel_stats`` and ``energy_columns``) guards against
    half-finished model modules: any failure selects :class:`FallbackModel`.
    """
    try:
        model = DramModel()
        model.linear(model.kernel_stats8("triad", 4096, 2, 1))
        model.linear(model.idle_stats(0.01))
        model._cache.clear()
        return model
    except Exception:  # the DRAM model is not (fully) there: fall back, never fail the source
        return FallbackModel()


class TruthModel:
    """Hidden per-DIMM currents: datasheet × seeded ratios in [0.35, 0.85], with aging and temperature.

    Ratios: a base ratio per current drawn in [0.40, 0.80], times a per-DIMM factor in [0.90, 1.10],
    clipped to [0.35, 0.85]. Drift: every current × (1 + ``aging_per_h`` × hours since open);
    temperature of DIMM d, T = 40 °C + ``temp_amp_c`` × sin(2π t / 1 h + φ_d), background currents
    × (1 + 0.5 %/K (T − 40)), the others × (1 + 0.1 %/K (T − 40)).
    """

    def __init__(self, names: tuple[str, ...], datasheet: np.ndarray, seed: int, *,
                 aging_per_h: float = 0.005, temp_amp_c: float = 3.0, dimm_spread: float = 0.10) -> None:
        rng = np.random.default_rng([int(seed), 7919])
        base = rng.uniform(0.40, 0.80, size=len(names))
        per_dimm = rng.uniform(1.0 - dimm_spread, 1.0 + dimm_spread, size=(len(DIMMS), len(names)))
        self.names = names
        self.datasheet = np.asarray(datasheet, dtype=float)
        self.ratio = np.clip(base[None, :] * per_dimm, 0.35, 0.85)
        self.phase = rng.uniform(0.0, 2 * math.pi, size=len(DIMMS))
        self.aging_per_h = aging_per_h
        self.temp_amp_c = temp_amp_c
        self.tempco = np.array([0.005 if n in _BACKGROUND else 0.001 for n in names])

    def temperature_c(self, t_s: float) -> np.ndarray:
        """DIMM temperatures (°C) at ``t_s`` seconds of sim time."""
        return 40.0 + self.temp_amp_c * np.sin(2 * math.pi * t_s / 3600.0 + self.phase)

    def currents(self, t_s: float) -> np.ndarray:
        """True currents (A per device), shape (8 DIMMs, len(names)), at ``t_s`` seconds of sim time."""
        aging = 1.0 + self.aging_per_h * t_s / 3600.0
        temp = 1.0 + self.tempco[None, :] * (self.temperature_c(t_s) - 40.0)[:, None]
        return self.datasheet[None, :] * self.ratio * aging * temp


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
    """

    run_id: str
    t0_ns: int
    duration_ns: int
    bg_w: np.ndarray
    dyn_j: np.ndarray
    io_j: np.ndarray
    idle_w: np.ndarray
    threads: tuple[int, int]
    traffic_end_ns: int
    cpu_end_ns: int | None = None

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
    """Idle power (W) per DIMM for per-DIMM ``currents`` (8 × names)."""
    cached = getattr(model, "_idle_per_s", None)
    if cached is None:
        cached = model.linear(model.idle_stats(1.0))
        model._idle_per_s = cached  # type: ignore[union-attr]
    cols, const = cached
    return np.asarray(currents @ cols + const, dtype=float)


def plan_run(model: Model, currents: np.ndarray, run_id: str, t0_ns: int, kernel: str, elements: int,
             threads: int, repeat: int, io_j_per_line: float) -> RunPlan:
    """The energy plan of a run starting at ``t0_ns`` with the true ``currents`` (8 × names) then."""
    idle = idle_power_w(model, currents)
    tps = threads_per_socket(threads)
    traffic = kernel_traffic_lines(kernel, elements)
    rate = modelled_line_rate(kernel, threads)
    zeros = np.zeros(len(DIMMS))
    if traffic is None or rate <= 0 or repeat <= 0 or sum(traffic) == 0:
        return RunPlan(run_id, t0_ns, 0, zeros, zeros, zeros, idle, tps, t0_ns)
    lines = float(sum(traffic) * repeat)
    duration_s = lines / rate
    stats8 = model.kernel_stats8(kernel, elements, threads, repeat)
    shares = socket_shares(threads)
    bg, dyn, io = zeros.copy(), zeros.copy(), zeros.copy()
    for socket in (0, 1):
        c1, k1 = _dimm_linear(model, stats8, shares[socket], duration_s)
        c2, k2 = _dimm_linear(model, stats8, shares[socket], 2 * duration_s)
        for d in range(len(DIMMS)):
            if DIMM_SOCKET[d] != socket:
                continue
            if shares[socket] <= 0:   # no traffic on this socket: the DIMM stays idle
                bg[d] = idle[d]
                continue
            e1 = float(currents[d] @ c1 + k1)
            e2 = float(currents[d] @ c2 + k2)
            bg[d] = (e2 - e1) / duration_s
            dyn[d] = e1 - bg[d] * duration_s
            io[d] = io_j_per_line * lines * shares[socket] / CHANNELS_PER_SOCKET
    d_ns = max(1, round(duration_s * 1e9))
    return RunPlan(run_id, t0_ns, d_ns, bg, dyn, io, idle, tps, t0_ns + d_ns)


def run_truth_energy_j(model: Model, currents: np.ndarray, kernel: str, elements: int, threads: int,
                       repeat: int, window_s: float) -> float:
    """Core energy (J) of the 8 DIMMs for a run evaluated over ``window_s`` (no I/O, no offsets)."""
    stats8 = model.kernel_stats8(kernel, elements, threads, repeat)
    shares = socket_shares(threads)
    total = 0.0
    for d in range(len(DIMMS)):
        cols, const = _dimm_linear(model, stats8, shares[DIMM_SOCKET[d]], window_s)
        total += float(currents[d] @ cols + const)
    return total


def _dimm_linear(model: Model, stats8: CommandStats, share: float, window_s: float) -> tuple[np.ndarray, float]:
    """Linear energy of a DIMM on a socket carrying ``share`` of the run's traffic, over ``window_s``.

    A DIMM without traffic stays idle (precharge standby + refresh), as on the real node where the
    DIMM pairs of an unused socket stay flat.
    """
    if share <= 0:
        return model.linear(model.idle_stats(window_s))
    return model.linear(stretch_stats(stats8, share * 8 / CHANNELS_PER_SOCKET, window_s, model.tck_s))
