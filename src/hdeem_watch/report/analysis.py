"""The numbers behind the figures: pure functions over report records (no I/O, no plotting).

Example:
    >>> from hdeem_watch.report.records import RunRow
    >>> runs = [RunRow("r1", "t", "triad", 24, 1, 2.0, 10.0, 20.0, 11.0),
    ...         RunRow("r2", "t", "triad", 24, 2, 2.0, 12.0, 22.0, 11.0)]
    >>> [(g.label, g.measured_j, round(g.calibrated_error_pct, 2)) for g in energy_groups(runs)]
    [('triad 24t', 11.0, 0.0)]
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from datetime import UTC
from typing import Any

import numpy as np

from hdeem_watch.dram.energy import COMPONENT_KINDS, component_energy
from hdeem_watch.dram.kernels import HOLDOUT_KERNELS
from hdeem_watch.errors import InputError
from hdeem_watch.fit_record import FitRecord
from hdeem_watch.report.records import BaselinePoint, FitEntry, JobRow, ReportData, RunRow, finite
from hdeem_watch.run_record import RunRecord

#: Energy components of the figure "energy by component": :data:`hdeem_watch.dram.energy.COMPONENT_KINDS`
#: under the figure's labels, in its order.
COMPONENT_GROUPS: dict[str, tuple[str, ...]] = {
    label: COMPONENT_KINDS[kind] for kind, label in (("activation", "ACT/PRE"), ("read", "RD"), ("write", "WR"),
                                                     ("background", "background"), ("refresh", "refresh"),
                                                     ("power_down", "power-down"))}


def model_currents(spec: Any, fit: FitRecord | None) -> tuple[np.ndarray, float]:
    """Every current of the energy model (``energy.CURRENT_NAMES`` order, A) and the intercept (J):
    the fit's calibrated values where it has them, the datasheet's elsewhere (as the daemon does)."""
    from hdeem_watch.dram.energy import CURRENT_NAMES

    values = {name: float(spec.currents.get(name, 0.0)) for name in CURRENT_NAMES}
    intercept = 0.0
    if fit is not None:
        for name, value in fit.calibrated_a.items():
            if name in values and math.isfinite(value):
                values[name] = value
        intercept = fit.intercept_j if math.isfinite(fit.intercept_j) else 0.0
    return np.array([values[name] for name in CURRENT_NAMES]), intercept


@dataclass(frozen=True)
class EnergyGroup:
    """Mean energies of the runs of one kernel and thread count (J)."""

    label: str
    kernel: str
    threads: int
    n: int
    measured_j: float
    datasheet_j: float
    calibrated_j: float

    @property
    def datasheet_error_pct(self) -> float:
        """Datasheet model against the measurement, % (mean energies)."""
        return (self.datasheet_j - self.measured_j) / self.measured_j * 100.0

    @property
    def calibrated_error_pct(self) -> float:
        """Calibrated model against the measurement, % (mean energies)."""
        return (self.calibrated_j - self.measured_j) / self.measured_j * 100.0


def energy_groups(runs: Iterable[RunRow]) -> list[EnergyGroup]:
    """Runs grouped by kernel and thread count (idle first, then kernels by name and threads)."""
    buckets: dict[tuple[str, int], list[RunRow]] = {}
    for run in runs:
        threads = 0 if run.kernel == "idle" else run.threads
        buckets.setdefault((run.kernel, threads), []).append(run)
    out = []
    for (kernel, threads), rows in sorted(buckets.items(), key=lambda kv: (kv[0][0] != "idle", kv[0])):
        out.append(EnergyGroup(label=rows[0].label, kernel=kernel, threads=threads, n=len(rows),
                               measured_j=float(np.mean([r.measured_j for r in rows])),
                               datasheet_j=float(np.mean([r.datasheet_j for r in rows])),
                               calibrated_j=float(np.mean([r.calibrated_j for r in rows]))))
    return out


def holdout_groups(runs: Iterable[RunRow]) -> list[EnergyGroup]:
    """Hold-out runs (:data:`~hdeem_watch.dram.kernels.HOLDOUT_KERNELS`, never fitted) with a
    measurement and a prediction from before each run, grouped by kernel (in that list's order) and
    thread count; ``calibrated_j`` is the mean prediction."""
    buckets: dict[tuple[str, int], list[RunRow]] = {}
    for run in runs:
        if run.kernel in HOLDOUT_KERNELS and run.measured_j > 0 and math.isfinite(run.predicted_j) \
                and math.isfinite(run.datasheet_j):
            buckets.setdefault((run.kernel, run.threads), []).append(run)
    order = {k: i for i, k in enumerate(HOLDOUT_KERNELS)}
    return [EnergyGroup(label=f"{kernel}-{threads}t", kernel=kernel, threads=threads, n=len(rows),
                        measured_j=float(np.mean([r.measured_j for r in rows])),
                        datasheet_j=float(np.mean([r.datasheet_j for r in rows])),
                        calibrated_j=float(np.mean([r.predicted_j for r in rows])))
            for (kernel, threads), rows in sorted(buckets.items(), key=lambda kv: (order[kv[0][0]], kv[0][1]))]


def drift_flags(history: Sequence[FitEntry], lag_s: float | None) -> list[dict[str, bool]]:
    """For each fit of the history, the currents the calibrator's drift rule flags at that fit.

    The rule of :meth:`hdeem_watch.calibrate.OnlineCalibrator.drift`: a current has drifted when the
    fit puts it outside the 95 % interval of the newest fit at least ``lag_s`` older, both fits
    determining it. Without a lag nothing is flagged.
    """
    flags: list[dict[str, bool]] = []
    for i, entry in enumerate(history):
        current = entry.fit
        row: dict[str, bool] = {}
        flags.append(row)
        if current is None or lag_s is None:
            continue
        cutoff = entry.t_ns - lag_s * 1e9
        reference = next((h.fit for h in reversed(history[:i]) if h.fit is not None and h.t_ns <= cutoff), None)
        if reference is None:
            continue
        for name, now in current.currents.items():
            before = reference.currents.get(name)
            if before is None:
                continue
            low, high = before.ci95_a
            usable = bool(before.identifiable and now.identifiable) and math.isfinite(low + high)
            row[name] = bool(usable and not low <= now.calibrated_a <= high)
    return flags


def run_groups(spec: Any, run: RunRow) -> list[tuple[Any, float]]:
    """The run's command statistics per channel group: as given, or re-modelled the way the daemon does."""
    if run.stats_groups is not None:
        return [(stats, float(n)) for stats, n in run.stats_groups]
    from hdeem_watch.dram.node import node_run_stats, topology_for

    topology = topology_for(run.dimms or 8)
    return [(stats, float(n)) for stats, n in node_run_stats(spec, run.kernel, run.elements, max(1, run.threads),
                                                               run.repeat, topology)]


def component_energies(spec: Any, fit: FitRecord | None, run: RunRow) -> dict[str, float]:
    """Energy of each of :data:`COMPONENT_GROUPS` for one run with the calibrated currents (J).

    The statistics are stretched over the measured window (:func:`hdeem_watch.dram.energy.component_energy`);
    the fit's intercept is its own entry (``offset``). For a run that announced its traffic time
    the calibration row ended the traffic there, so the figure's sum can differ from the row's
    prediction by that idle tail's share (the record carries no traffic time).
    """
    currents, intercept = model_currents(spec, fit)
    per_component = component_energy(spec, run_groups(spec, run), run.window_s, currents, name=run.name)
    totals = {group: float(sum(per_component[part] for part in parts)) for group, parts in COMPONENT_GROUPS.items()}
    totals["offset"] = intercept
    return totals


def representative_runs(runs: Sequence[RunRow]) -> list[RunRow]:
    """Per kernel, its latest run at its highest thread count (idle first, then by kernel name)."""
    best: dict[str, RunRow] = {}
    for run in runs:
        kept = best.get(run.kernel)
        if kept is None or (run.threads, run.t_ns) >= (kept.threads, kept.t_ns):
            best[run.kernel] = run
    return [best[k] for k in sorted(best, key=lambda k: (k != "idle", k))]


def jobs_from_runs(records: Sequence[RunRecord], baselines: Sequence[BaselinePoint]) -> list[JobRow]:
    """Jobs from the runs' SLURM metadata (``slurm_job_id``): summed DRAM energy, and the energy the
    idle baseline (each channel's latest before the run) would have drawn over the same windows."""
    jobs: dict[tuple[str, str], list[float]] = {}
    for record in records:
        job = record.metadata.get("slurm_job_id")
        energy, window = finite(record.dram_energy_j), finite(record.window_s)
        if not job or record.state != "done" or not math.isfinite(energy) or not math.isfinite(window):
            continue
        t_ns = record.t_start_ns or 0
        channels = [c for c in record.energy_j or {} if c.lower().startswith(("ddr", "dram"))]
        powers = [_baseline_before(baselines, c, t_ns) for c in channels]
        baseline = sum(powers) * window if powers else math.nan
        node = str(record.node or record.metadata.get("slurm_node") or "")
        entry = jobs.setdefault((str(job), node), [0.0, 0.0, 0.0, 0.0])
        entry[0] += energy
        entry[1] += baseline
        entry[2] += window
        entry[3] += 1
    return [JobRow(job_id=job, node=node, dram_energy_j=v[0], baseline_j=v[1], window_s=v[2], runs=int(v[3]))
            for (job, node), v in sorted(jobs.items())]


def _baseline_before(baselines: Sequence[BaselinePoint], channel: str, t_ns: int) -> float:
    earlier = [b for b in baselines if b.channel == channel and b.t_ns <= t_ns]
    return earlier[-1].power_w if earlier else math.nan


_DURATION = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*(s|m|h|d|w)\s*$")
_UNIT_S = {"s": 1.0, "m": 60.0, "h": 3600.0, "d": 86400.0, "w": 7 * 86400.0}


def parse_since(text: str, now_ns: int) -> int:
    """``--since``: an age (``90m``, ``12h``, ``7d``, ``2w``) before ``now_ns``, or an ISO 8601 date or
    time (UTC unless it names its offset) → wall-clock ns.

    Raises:
        InputError: neither form.

    Example:
        >>> parse_since("2h", 10_000 * 10**9) // 10**9
        2800
        >>> parse_since("2026-01-01T00:00:00+00:00", 0) // 10**9
        1767225600
    """
    from datetime import datetime

    match = _DURATION.match(text)
    if match:
        return int(now_ns - float(match.group(1)) * _UNIT_S[match.group(2)] * 1e9)
    try:
        moment = datetime.fromisoformat(text.strip())
    except ValueError:
        raise InputError(f"--since {text!r}: expected an age like 12h/7d or an ISO date/time like "
                         "2026-11-01 or 2026-11-01T08:00+01:00") from None
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=UTC)
    return int(moment.timestamp() * 1e9)


def select(data: ReportData, *, since_ns: int | None = None, group: str | None = None) -> ReportData:
    """``data`` restricted to runs, fits, baselines and jobs from ``since_ns`` on, and to the DIMM pair
    ``group`` (``node`` or None = all) for the per-pair figures.

    Raises:
        InputError: a group the data does not have.
    """
    notes = list(data.notes)
    if group not in (None, "node") and group not in data.channels:
        known = ", ".join(("node", *data.channels))
        raise InputError(f"--group {group!r}: not a DRAM channel of this input; expected one of {known}")
    if since_ns is not None:
        runs = tuple(r for r in data.runs if r.t_ns >= since_ns)
        history = tuple(h for h in data.fit_history if h.t_ns >= since_ns)
        baselines = tuple(b for b in data.baselines if b.t_ns >= since_ns)
        data = replace(data, runs=runs, fit_history=history, baselines=baselines)
    if group not in (None, "node"):
        data = replace(data, baselines=tuple(b for b in data.baselines if b.channel == group),
                       channels=(group,), pair_fits={k: v for k, v in data.pair_fits.items() if k == group})
        notes.append(f"per-pair figures restricted to {group}; the energy and current figures are the node's")
    return replace(data, notes=tuple(notes))
