"""Realistic calibration data from the REAL models: controller statistics of the STREAM-like kernels,
the energy model, a node bandwidth model, a hidden truth, noise and an unmodelled offset.

The node: 8 identical DIMMs of the Samsung M393A1G43DB0-CPB (2 ranks × 9 x8 devices), one per
channel; every DIMM carries 1/8 of a run's traffic (``kernel_stats(..., channels=8, xor_bank=True)``)
and the measured energy is the 8 DIMMs' (``scale = 8``). A run lasts as long as the node needs to
move its lines: each thread streams 7 GB/s, a socket (12 cores) saturates at 58 GB/s (smooth
minimum), kernels that write lose 12 % to turnarounds, and no DIMM is faster than its controller
model (``cycles × tCK``). The actual window is that modelled duration × U(0.97, 1.03); the truth
energy is the energy model over the actual window with the truth currents (the DIMM refreshes and
idles in standby over the whole window, as ``observation_from_run`` assumes).

:data:`DESIGN` is the run design the documentation recommends (docs/calibration.md, "Which runs
determine which current"): read-only at 1–24 threads (IDD3N at low bandwidth, IDD4R at high
bandwidth with few row misses, IDD0 at 20–24 threads where the interleaved streams miss the row
buffer), the write-heaviest kernels (assign, selfscale: half the traffic writes) at low to saturated
bandwidth for IDD4W, mixed kernels (scale, add) at 1 and high thread counts, and idle runs of
1–30 s for IDD2N and the per-run offset.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

#: DIMMs of the node; each carries 1/DIMMS of the traffic.
DIMMS = 8
#: Doubles per array (320 MB per array: far beyond any cache).
ELEMENTS = 40_000_000
PER_THREAD_BPS = 7.0e9
SOCKET_MAX_BPS = 58.0e9
WRITE_FACTOR = 0.88
CORES_PER_SOCKET = 12
LINE_BYTES = 64
#: The five currents the calibrator fits by default.
CURRENTS = ("idd0", "idd2n", "idd3n", "idd4r", "idd4w")
#: The recommended 20-run design: 16 (kernel, threads) runs + idle runs of these lengths (s).
DESIGN: tuple[tuple[str, int], ...] = (
    ("read", 1), ("read", 4), ("read", 12), ("read", 16), ("read", 20), ("read", 24),
    ("assign", 1), ("assign", 12), ("assign", 16), ("assign", 24), ("selfscale", 2),
    ("add", 1), ("add", 20), ("add", 24), ("scale", 1), ("scale", 12),
)
IDLE_S: tuple[float, ...] = (1.0, 5.0, 10.0, 30.0)
#: A design a user might do without guidance (every kernel, a few thread counts, short idle runs).
NAIVE_DESIGN: tuple[tuple[str, int], ...] = (
    ("read", 1), ("read", 4), ("read", 12), ("read", 24), ("assign", 2), ("assign", 8), ("assign", 24),
    ("copy", 1), ("copy", 6), ("copy", 24), ("add", 4), ("add", 16), ("triad", 2), ("triad", 12),
    ("scale", 8), ("selfscale", 3),
)
NAIVE_IDLE_S: tuple[float, ...] = (1.0, 2.0, 5.0, 10.0)


def node_line_rate(kernel: str, threads: int) -> float:
    """64-byte lines per second the node moves for ``kernel`` with ``threads`` threads (socket 0
    filled first)."""
    def socket(n: int) -> float:
        if n <= 0:
            return 0.0
        x = n * PER_THREAD_BPS
        return float((x ** -4 + SOCKET_MAX_BPS ** -4) ** -0.25)

    s0 = min(threads, CORES_PER_SOCKET)
    s1 = max(0, min(threads - CORES_PER_SOCKET, CORES_PER_SOCKET))
    bps = socket(s0) + socket(s1)
    if kernel != "read":
        bps *= WRITE_FACTOR
    return bps / LINE_BYTES


@dataclass(frozen=True)
class Planned:
    """One kernel configuration: the statistics of one pass on one DIMM and how long a pass takes."""

    name: str
    stats: Any
    pass_s: float


def plan(spec: Any, design: tuple[tuple[str, int], ...] = DESIGN) -> list[Planned]:
    """One pass of every (kernel, threads) of ``design`` through the controller model."""
    from hdeem_watch.dram.kernels import kernel_stats, kernel_traffic

    out = []
    for kernel, threads in design:
        model = kernel_stats(spec, kernel, ELEMENTS, threads, repeat=1, channels=DIMMS, xor_bank=True)
        traffic = kernel_traffic(kernel, ELEMENTS)
        node_s = (traffic.lines_read + traffic.lines_written) / node_line_rate(kernel, threads)
        out.append(Planned(f"{kernel}-{threads}t", model.stats, max(node_s, model.cycles * spec.tck_s)))
    return out


def draw_runs(planned: list[Planned], idle_s: tuple[float, ...], rng: np.random.Generator
              ) -> list[tuple[str, Any, float]]:
    """``(name, model_stats, window_s)``: each kernel repeated to last 1–4 s, the window its
    modelled duration × U(0.97, 1.03); idle runs (statistics without commands) of ``idle_s``."""
    from hdeem_watch.dram.stats import CommandStats, RankStats

    runs = []
    for p in planned:
        repeat = max(1, round(float(rng.uniform(1.0, 4.0)) / p.pass_s))
        window = p.pass_s * repeat * float(rng.uniform(0.97, 1.03))
        runs.append((f"{p.name}x{repeat}", p.stats.scaled(repeat), window))
    for seconds in idle_s:
        empty = CommandStats(ranks=(RankStats(), RankStats()))
        runs.append((f"idle-{seconds:g}s", empty, seconds * float(rng.uniform(0.97, 1.03))))
    return runs


def draw_truth(spec: Any, rng: np.random.Generator) -> dict[str, float]:
    """Hidden currents: each of :data:`CURRENTS` = datasheet × U(0.35, 0.85), drawn again until
    they are physically consistent (IDD3N ≥ IDD2N, IDD4R/IDD4W ≥ IDD3N, ...:
    :mod:`hdeem_watch.dram.memspec_check`), as a real device's are."""
    from hdeem_watch.dram.memspec_check import physical_violations

    while True:
        truth = {name: float(spec.currents[name] * rng.uniform(0.35, 0.85)) for name in CURRENTS}
        if not physical_violations(spec.with_currents(truth)):
            return truth


def observations(spec: Any, runs: list[tuple[str, Any, float]], truth: dict[str, float],
                 rng: np.random.Generator, *, noise: float = 0.01, offset: float = 0.02,
                 offset_kind: str = "energy") -> list[Any]:
    """Rows of ``runs`` measured on ``truth``: the 8 DIMMs' core energy over the window, plus an
    unmodelled offset of ``offset`` × the mean run energy — ``"energy"``: the same joules in every
    run; ``"power"``: a constant power (``offset`` × the mean run power, joules ∝ window) — times
    (1 + ``noise`` · N(0, 1))."""
    from hdeem_watch.calibrate import observation_from_run
    from hdeem_watch.dram.energy import core_energy
    from hdeem_watch.dram.stats import stretch_stats

    truth_spec = spec.with_currents(truth)
    energies = np.array([core_energy(truth_spec, stretch_stats(spec, s, w)).core_j * DIMMS for _, s, w in runs])
    windows = np.array([w for _, _, w in runs])
    if offset_kind == "energy":
        extra = np.full(len(runs), offset * energies.mean())
    elif offset_kind == "power":
        extra = offset * (energies / windows).mean() * windows
    else:
        raise ValueError(offset_kind)
    measured = (energies + extra) * (1.0 + noise * rng.standard_normal(len(runs)))
    return [observation_from_run(spec, s, w, float(m), scale=DIMMS, name=n)
            for (n, s, w), m in zip(runs, measured)]
