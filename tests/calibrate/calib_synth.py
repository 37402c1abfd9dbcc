"""Synthetic DDR4 rows for the calibrator's tests (no energy model needed).

A small stand-in for the model's linear decomposition with ρ = 1, Iβ = I0 (DESIGN.md §3), in units
of J per A for one rank of ``devices`` devices, so the numerical core can be tested on its own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

NAMES = ("idd0", "idd2n", "idd3n", "idd4r", "idd4w", "idd5b", "idd6n", "idd2p", "idd3p")
DATASHEET = {"idd0": 0.0585, "idd2n": 0.036, "idd3n": 0.04175, "idd4r": 0.171, "idd4w": 0.151875,
             "idd5b": 0.118, "idd6n": 0.02025, "idd2p": 0.017, "idd3p": 0.0225}
TCK_S = 0.9375e-9
RAS, RP, RFC, REFI, BURST = 36, 15, 278, 8320, 4
VDD = 1.2


@dataclass(frozen=True)
class Spec:
    """Just what the fit reads of a memspec."""

    currents: dict


def spec(currents: dict | None = None) -> Spec:
    """A spec-like object with the synthetic datasheet currents."""
    return Spec(dict(DATASHEET if currents is None else currents))


def columns(acts: float, reads: float, writes: float, seconds: float, active_frac: float, *,
            ranks: int = 2, devices: int = 8) -> np.ndarray:
    """J per A over NAMES for a window of ``seconds`` with these command totals (split over ranks)."""
    t = seconds / TCK_S / 1.0
    unit = VDD * TCK_S * devices
    out = np.zeros(len(NAMES))
    for _ in range(ranks):
        a, r, w = acts / ranks, reads / ranks, writes / ranks
        refs = t / REFI
        t_act = max(active_frac * t, RAS * a + BURST * (r + w) + RFC * refs)
        t_pre = t - t_act
        c = dict.fromkeys(NAMES, 0.0)
        c["idd0"] = (RAS + RP) * a
        c["idd4r"] = BURST * r
        c["idd4w"] = BURST * w
        c["idd5b"] = RFC * refs
        c["idd3n"] = t_act - RAS * a - BURST * (r + w) - RFC * refs
        c["idd2n"] = t_pre - RP * a
        out += np.array([c[n] for n in NAMES]) * unit
    return out


def kernel_mix(rng: np.random.Generator, n: int, *, idle: int = 2,
               writes: bool = True) -> list[tuple[np.ndarray, float]]:
    """``n`` varied runs ``(columns, seconds)``: kernels with different read/write/activation mixes
    and durations; the first ``idle`` are idle (no commands)."""
    rows = []
    ratios = [(1, 0), (1, 1), (2, 1), (1, 2), (0, 1), (3, 1)] if writes else [(1, 0)]
    for i in range(n):
        seconds = float(rng.uniform(0.5, 4.0))
        if i < idle:
            rows.append((columns(0, 0, 0, seconds, 0.0), seconds))
            continue
        rd, wr = ratios[i % len(ratios)]
        bw = rng.uniform(0.1, 1.0) * 5e8  # bursts per second per channel at most
        total = bw * seconds
        reads = total * rd / (rd + wr)
        writes_n = total * wr / (rd + wr)
        hit = rng.uniform(0.0, 0.95)  # row-buffer hit rate
        acts = total * (1 - hit) / 4 + 1
        rows.append((columns(acts, reads, writes_n, seconds, rng.uniform(0.2, 0.95)), seconds))
    return rows


#: Physically consistent (IDD0 ≥ IDD3N ≥ IDD2N, IDD3N ≥ IDD3P, ...: dram/memspec_check.py), also
#: after test_online's aging takes 30 % off IDD3N.
TRUTH_RATIOS = {"idd0": 0.8, "idd2n": 0.58, "idd3n": 0.9, "idd4r": 0.55, "idd4w": 0.45}


def truth_vector(truth: dict) -> np.ndarray:
    """``truth`` in NAMES order."""
    return np.array([truth[n] for n in NAMES])


def observations(rng: np.random.Generator, runs: list, truth: dict, *, noise: float = 0.0,
                 offset_j: float = 0.0, offset_w: float = 0.0, t0_ns: int = 0, dt_ns: int = 0):
    """Observations of ``runs`` (from :func:`kernel_mix`) measured on ``truth`` with relative
    Gaussian ``noise``, a constant ``offset_j`` per run and a constant ``offset_w`` power."""
    from hdeem_watch.calibrate import Observation

    current = truth_vector(truth)
    out = []
    for i, (cols, seconds) in enumerate(runs):
        energy = cols @ current + offset_j + offset_w * seconds
        measured = energy * (1.0 + noise * rng.standard_normal())
        out.append(Observation(f"run{i}", cols, 0.0, float(measured), time_ns=t0_ns + i * dt_ns,
                               window_s=seconds))
    return out


#: Per element pass: (reads, writes) in 64-byte lines, write-allocate included (DESIGN.md §3);
#: ``-nt``: non-temporal stores (no write-allocate read).
KERNEL_TRAFFIC = {"read": (1, 0), "assign": (1, 1), "scale": (2, 1), "add": (3, 1), "triad": (2, 1),
                  "copy": (2, 1), "selfscale": (1, 1), "assign-nt": (0, 1), "copy-nt": (1, 1)}


def kernel_command_stats(spec, kernel: str, threads: int, seconds: float, *, ranks: int = 2,
                         pattern: str = "stream"):
    """Plausible one-channel :class:`CommandStats` of a STREAM-like kernel run.

    Bandwidth grows with threads and saturates; more threads interleave more streams, so the
    row-buffer hit rate falls and activations rise; banks are open a larger share of the time at
    higher bandwidth. ``pattern="random"`` (one line per row visit) misses the row buffer nearly
    always and moves less data; ``"closed"`` closes each bank right after its access. Not a controller simulation: just varied, self-consistent statistics.
    """
    from hdeem_watch.dram.stats import CommandStats, RankStats

    reads_per, writes_per = KERNEL_TRAFFIC[kernel]
    cycles = seconds / spec.tck_s
    util = min(0.85, 0.09 * threads ** 0.8)  # data-bus utilisation of the channel
    bursts = util * cycles / spec.burst_cycles
    hit = max(0.55, 0.97 - 0.018 * threads)
    if pattern == "random":
        util, hit = util * 0.35, 0.05
    act_frac = 1.0 - 0.75 * math.exp(-4.0 * util)  # open page: banks stay open once traffic flows
    if pattern == "closed":  # closed-page controller: a bank closes right after its access
        hit, act_frac = 0.0, min(0.9, 0.05 + 0.6 * util)
    rd = bursts * reads_per / (reads_per + writes_per)
    wr = bursts * writes_per / (reads_per + writes_per)
    act = bursts * (1 - hit)
    ref = cycles / spec.timings["REFI"]
    rank_stats = []
    for _ in range(ranks):
        t_act = act_frac * cycles
        rank_stats.append(RankStats(act=act / ranks, pre=act / ranks, rd=rd / ranks, wr=wr / ranks,
                                    ref=ref, cycles_total=cycles, cycles_act=t_act,
                                    cycles_pre=cycles - t_act, bank_active_cycles=t_act * 3.0))
    return CommandStats(ranks=tuple(rank_stats))


def idle_stats(spec, seconds: float, *, ranks: int = 2):
    """An idle (compute-only) run: no commands but refresh, all banks precharged."""
    from hdeem_watch.dram.stats import CommandStats, RankStats

    cycles = seconds / spec.tck_s
    ref = cycles / spec.timings["REFI"]
    rank = RankStats(ref=ref, cycles_total=cycles, cycles_act=ref * spec.trfc, cycles_pre=cycles - ref * spec.trfc,
                     bank_active_cycles=ref * spec.trfc * spec.nbr_of_banks)
    return CommandStats(ranks=(rank,) * ranks)


def realistic_runs(spec, rng: np.random.Generator, *, n_kernel: int = 18, n_idle: int = 2):
    """``(name, model_stats, window_s)`` of varied kernel runs (kernels × threads, every third one a
    random-access pattern, 0.5–3 s) and idle runs; the measured window is the modelled one
    stretched by up to ±10 %."""
    kernels = list(KERNEL_TRAFFIC)
    threads = [1, 2, 4, 8, 12, 24]
    runs = []
    for i in range(n_kernel):
        kernel = kernels[i % len(kernels)]
        t = threads[(i * 5 + i // len(kernels)) % len(threads)]
        seconds = float(rng.uniform(0.5, 3.0))
        window = seconds * float(rng.uniform(0.9, 1.1))
        pattern = "random" if i % 3 == 2 else "stream"
        runs.append((f"{kernel}-{t}t-{pattern}-{i}",
                     kernel_command_stats(spec, kernel, t, seconds, pattern=pattern), window))
    for i in range(n_idle):
        seconds = float(rng.uniform(0.5, 3.0))
        runs.append((f"idle-{i}", idle_stats(spec, seconds), seconds))
    return runs
