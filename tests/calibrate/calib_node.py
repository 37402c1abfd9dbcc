"""A synthetic node whose measurements are NOT the calibrator's model: per-group runs for the group
calibrators' tests and ``benchmarks/bench_calibration.py``.

The node is the Taurus Haswell-EP (2 sockets × 12 cores × 4 channels, one Samsung M393A1G43DB0-CPB
DIMM per channel; HDEEM sensors DDR_AB, DDR_CD on socket 0, DDR_EF, DDR_GH on socket 1). A run's
model statistics come from :func:`hdeem_watch.dram.node.node_run_stats` (what the daemon models);
its measured energy per sensor is the energy model with the *group's* hidden currents plus what the
model leaves out:

- part variation: each group's currents are the node truth × U(0.9, 1.1) per current (kept
  physically consistent);
- I/O and termination energy: ``IO_J_PER_BURST`` per read/write burst;
- power-down: an idle socket's DIMMs draw ``POWER_DOWN_SAVING`` less background (the controller
  enters power-down after idle time; the model keeps them in standby);
- temperature refresh: runs of more than 16 threads refresh twice as often (DIMMs above 85 °C);
- per-sensor gain (1 ± 2 %) and offset (± 0.05 W), 0.5 % noise per run and 0.125 W quantisation of
  each 100 Sa/s sample (averaged over the window);
- aging: ``aging = {group: fraction per hour}`` multiplies that group's currents by
  ``1 + fraction × hours since age_start_s`` (sim time).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

IO_J_PER_BURST = 0.5e-9
POWER_DOWN_SAVING = 0.03
GROUPS = (("DDR_AB", (2, 0)), ("DDR_CD", (2, 0)), ("DDR_EF", (0, 2)), ("DDR_GH", (0, 2)))
CURRENTS = ("idd0", "idd2n", "idd3n", "idd4r", "idd4w")
#: (kernel, threads) of the run mix: both sockets busy, one busy, different read/write mixes.
MIX = (("read", 4), ("read", 12), ("read", 24), ("assign", 6), ("assign", 24), ("copy", 2), ("copy", 18),
       ("add", 12), ("add", 24), ("scale", 8), ("triad", 20), ("selfscale", 16), ("idle", 0), ("idle", 0))
ELEMENTS = 8_000_000


def sensor_groups() -> list[Any]:
    """The four HDEEM pair groups of the node."""
    from hdeem_watch.calibrate.groups import SensorGroup

    return [SensorGroup(name, counts) for name, counts in GROUPS]


@dataclass
class Planned:
    """One configuration: the model's per-socket statistics of one pass and the pass time."""

    kernel: str
    threads: int
    socket_stats: tuple[Any, ...]
    pass_s: float


def plan(spec: Any) -> list[Planned]:
    """Every configuration of :data:`MIX` through the node model (once; ~0.2 s)."""
    from hdeem_watch.dram.node import HASWELL_EP, node_run_stats

    out = []
    for kernel, threads in MIX:
        groups = tuple(node_run_stats(spec, kernel, ELEMENTS, threads, 1, HASWELL_EP))
        cycles = max((r.cycles_total for stats, _n in groups for r in stats.ranks), default=0.0)
        out.append(Planned(kernel, threads, groups, max(cycles * float(spec.tck_s), 1e-3)))
    return out


def physical_draw(spec: Any, rng: np.random.Generator, base: dict[str, float], spread: float) -> dict[str, float]:
    """``base × U(1 − spread, 1 + spread)`` per current, drawn again until physically consistent."""
    from hdeem_watch.dram.memspec_check import physical_violations

    for _ in range(1000):
        out = {n: base[n] * float(rng.uniform(1 - spread, 1 + spread)) for n in CURRENTS}
        if not physical_violations(spec.with_currents(out)):
            return out
    raise RuntimeError("no physically consistent draw")


class SyntheticNode:
    """Runs of the misspecified node (see the module docstring).

    Args:
        spec: the DIMMs' memspec (the model's and the datasheet).
        seed: everything random.
        aging: group → relative change of its currents per sim hour.
        age_start_s: sim time the aging starts.
        misspecified: False = measurements are exactly the model (plus noise).
        noise: False = no run noise and no quantisation (for the effective truth: what the
            model's currents converge to on these measurements).
    """

    def __init__(self, spec: Any, seed: int, *, aging: dict[str, float] | None = None, age_start_s: float = 0.0,
                 misspecified: bool = True, planned: list[Planned] | None = None, noise: bool = True) -> None:
        self.spec = spec
        self.rng = np.random.default_rng(seed)
        self.planned = planned if planned is not None else plan(spec)
        node = physical_draw(spec, self.rng, {n: spec.currents[n] * 0.75 for n in CURRENTS}, 0.15)
        self.truth = {name: physical_draw(spec, self.rng, node, 0.1 if misspecified else 0.0) for name, _ in GROUPS}
        self.gain = {name: float(1 + 0.02 * self.rng.uniform(-1, 1)) if misspecified else 1.0 for name, _ in GROUPS}
        self.offset_w = {name: float(0.05 * self.rng.uniform(-1, 1)) if misspecified else 0.0 for name, _ in GROUPS}
        self.aging = dict(aging or {})
        self.age_start_s = age_start_s
        self.misspecified = misspecified
        self.noise = noise
        self.clock_s = 0.0

    def truth_at(self, group: str, t_s: float) -> dict[str, float]:
        """The group's currents at sim time ``t_s``."""
        factor = 1.0 + self.aging.get(group, 0.0) * max(0.0, t_s - self.age_start_s) / 3600.0
        return {n: v * factor for n, v in self.truth[group].items()}

    def _energy(self, group: str, counts: tuple[int, ...], p: Planned, window_s: float, t_s: float,
                repeat: int) -> float:
        from hdeem_watch.dram.energy import core_energy
        from hdeem_watch.dram.stats import stretch_stats

        truth_spec = self.spec.with_currents(self.truth_at(group, t_s))
        total = 0.0
        for (stats, _n), k in zip(p.socket_stats, counts):
            if not k:
                continue
            scaled = stats.scaled(repeat)
            stretched = stretch_stats(self.spec, scaled, window_s)
            parts = core_energy(truth_spec, stretched)
            energy = parts.core_j
            if self.misspecified:
                bursts = scaled.total("rd") + scaled.total("wr")
                energy += IO_J_PER_BURST * bursts
                if bursts == 0:
                    energy -= POWER_DOWN_SAVING * parts.core_j
                if p.threads > 16:
                    energy += float(parts.components.get("refresh", 0.0))
            total += k * energy
        return total

    def run(self, *, config: int | None = None, duration_s: float | None = None, gap_s: float = 5.0) -> Any:
        """The next run (a :class:`~hdeem_watch.calibrate.groups.MeasuredRun`), back to back with the
        previous one after ``gap_s``; ``duration_s`` forces the window (e.g. 0.01 s)."""
        from hdeem_watch.calibrate.groups import MeasuredRun

        index = int(self.rng.integers(len(self.planned))) if config is None else config
        p = self.planned[index]
        if duration_s is None:
            repeat = max(1, round(float(self.rng.uniform(5.0, 30.0)) / p.pass_s))
            window = p.pass_s * repeat * float(self.rng.uniform(1.0, 1.2))
        else:
            repeat = max(1, round(duration_s / p.pass_s))
            window = duration_s
        if p.kernel == "idle":
            repeat = 1
            window = float(self.rng.uniform(5.0, 30.0)) if duration_s is None else duration_s
        t_s = self.clock_s + window
        self.clock_s = t_s + gap_s
        energies = {}
        for name, counts in GROUPS:
            e = self._energy(name, counts, p, window, t_s, repeat)
            e = e * self.gain[name] + self.offset_w[name] * window
            draws = self.rng.standard_normal(2)
            if self.noise:
                e *= 1 + 0.005 * float(draws[0])
                samples = max(1, int(window * 100))
                e += 0.125 / np.sqrt(12 * samples) * window * float(draws[1])
            energies[name] = e
        stats = tuple((s.scaled(repeat), n) for s, n in p.socket_stats)
        return MeasuredRun(f"{p.kernel}-{p.threads}t@{t_s:.0f}", int(t_s * 1e9), window, stats, energies,
                           {name: int(window * 100) for name, _ in GROUPS}, kind=f"{p.kernel}/{p.threads}")
