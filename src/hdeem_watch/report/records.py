"""What a report is drawn from: runs, fits, baselines and jobs as small frozen records.

Both readers (:mod:`hdeem_watch.report.state_reader` for the daemon's SQLite state and
:mod:`hdeem_watch.report.runs_reader` for a RUNS.json) produce one :class:`ReportData`; every
figure is a pure function of it. Unknown numbers are NaN, never 0.

Example:
    >>> run = RunRow(run_id="r1", name="triad-24t", kernel="triad", threads=24, t_ns=0, window_s=2.0,
    ...              measured_j=16.0, datasheet_j=30.0, calibrated_j=16.2)
    >>> round(run.error_pct("datasheet_j"), 1), round(run.error_pct("calibrated_j"), 2)
    (87.5, 1.25)
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from hdeem_watch.fit_record import FitRecord

NAN = math.nan


@dataclass(frozen=True)
class RunRow:
    """One measured run and the models' energies for it (all energies node totals in J).

    Attributes:
        run_id: the daemon's id (``r<n>``) or the RUNS.json index (``run[i]``).
        name: the run's name.
        kernel: the kernel (``idle`` for an idle run).
        threads: threads of the run (0 = unknown).
        t_ns: wall-clock end of the run, integer ns (0 = unknown).
        window_s: measured window (s).
        measured_j: measured DRAM energy.
        datasheet_j: the model with the datasheet currents.
        calibrated_j: the model with the latest fit's currents (and intercept).
        predicted_j: the model with the fit from *before* the run (out of sample; NaN = none).
        loo_j: the latest fit's leave-one-out prediction of this run (NaN = not in the fit).
        elements: elements per array (for re-modelling the run's commands; 0 = unknown/idle).
        repeat: passes over the arrays.
        dimms: DIMMs of the node the run was modelled on (0 = unknown).
        channel_energy_j: measured energy per DRAM channel (DIMM pair), J.
        stats_groups: the run's command statistics as ``((CommandStats, channels), ...)`` when the
            input carries them (RUNS.json); None = re-model from kernel/elements/threads/repeat.
    """

    run_id: str
    name: str
    kernel: str
    threads: int
    t_ns: int
    window_s: float
    measured_j: float
    datasheet_j: float = NAN
    calibrated_j: float = NAN
    predicted_j: float = NAN
    loo_j: float = NAN
    elements: int = 0
    repeat: int = 1
    dimms: int = 0
    channel_energy_j: Mapping[str, float] = field(default_factory=dict)
    stats_groups: tuple[tuple[Any, float], ...] | None = None

    @property
    def label(self) -> str:
        """``kernel threads`` as shown on axes (``idle`` alone for idle runs)."""
        if self.kernel == "idle" or self.threads <= 0:
            return self.kernel
        return f"{self.kernel} {self.threads}t"

    def error_pct(self, which: str) -> float:
        """Relative error of the model energy ``which`` (a field name) against the measurement, in %."""
        model = float(getattr(self, which))
        if not math.isfinite(model) or not self.measured_j > 0:
            return NAN
        return (model - self.measured_j) / self.measured_j * 100.0


@dataclass(frozen=True)
class FitEntry:
    """One fit of the history (None after a calibrator reset).

    Older fits of a daemon state are read without their per-run details and correlation matrix
    (only the newest is read whole); ``row`` is the fit's row id in the state (0 = none).
    """

    t_ns: int
    run_id: str | None
    fit: FitRecord | None
    row: int = 0


@dataclass(frozen=True)
class BaselinePoint:
    """An idle power of one DRAM channel at one time.

    Attributes:
        channel: the channel (DIMM pair), e.g. ``DDR_AB``.
        t_ns: wall-clock time (ns).
        power_w: mean idle power (W).
        spread_w: standard deviation of the samples (W; NaN = unknown).
        origin: ``idle-run`` (an idle run's window) or ``quiet`` (a quiet period the daemon found).
    """

    channel: str
    t_ns: int
    power_w: float
    spread_w: float
    origin: str


@dataclass(frozen=True)
class JobRow:
    """DRAM energy of one job on one node.

    Attributes:
        job_id: the job (e.g. the SLURM job id).
        node: the node.
        dram_energy_j: measured DRAM energy over the job's runs (J).
        baseline_j: the idle baseline's energy over the same windows (J; NaN = no baseline).
        window_s: summed run windows, or a SLURM job's measured time (s).
        runs: number of runs (None for a SLURM job's record: it counts none).
    """

    job_id: str
    node: str
    dram_energy_j: float
    baseline_j: float
    window_s: float
    runs: int | None

    @property
    def above_baseline_j(self) -> float:
        """Energy above the idle baseline (NaN without a baseline)."""
        return self.dram_energy_j - self.baseline_j


@dataclass(frozen=True)
class ReportData:
    """Everything a report shows, from one state or one RUNS.json.

    Attributes:
        source: what was read (shown on the page).
        spec: the datasheet memspec (:class:`~hdeem_watch.dram.memspec.MemSpec`), None if unknown.
        runs: finished runs, oldest first.
        fit: the latest fit, None without one.
        fit_history: every stored fit, oldest first.
        drift_lag_s: how far back the drift reference fit is (None = the calibrator flags no drift).
        baselines: idle baselines per channel over time, oldest first.
        jobs: job records (empty when the input has none).
        pair_fits: per DIMM-pair fits by channel (empty when the input has none).
        pair_history: each DIMM pair's fits over time, oldest first (the daemon's per-group
            calibrators; empty when the input has none).
        alarms: the daemon's drift alarms (``DriftAlarm.to_dict()``: ``group``, ``current``,
            ``kind``, ``time_ns``, ...), oldest first.
        channels: the DRAM channels (DIMM pairs) seen.
        notes: sentences the page shows about what the input lacks.
    """

    source: str
    spec: Any
    runs: tuple[RunRow, ...]
    fit: FitRecord | None
    fit_history: tuple[FitEntry, ...] = ()
    drift_lag_s: float | None = None
    baselines: tuple[BaselinePoint, ...] = ()
    jobs: tuple[JobRow, ...] = ()
    pair_fits: Mapping[str, FitRecord] = field(default_factory=dict)
    pair_history: Mapping[str, tuple[FitEntry, ...]] = field(default_factory=dict)
    alarms: tuple[Mapping[str, Any], ...] = ()
    channels: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()


def is_dram_channel(name: str) -> bool:
    """Whether a channel name is a DRAM channel (an HDEEM DIMM pair ``DDR_*`` or a RAPL ``dram*`` zone)."""
    lowered = name.lower()
    return lowered.startswith("ddr") or lowered.startswith("dram")


def finite(value: Any) -> float:
    """``value`` as a float, NaN for None, non-numbers and infinities."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return NAN
    number = float(value)
    return number if math.isfinite(number) else NAN
