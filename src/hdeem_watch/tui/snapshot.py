"""Immutable snapshots of what the UI shows about one node.

A background feed builds a :class:`NodeSnapshot` with a pure function (``model.NodeModel.snapshot``)
a few times per second; the app paints the newest one at a fixed rate. Nothing here refers to
sockets or to Textual, so tests build snapshots by hand (the snapshot tests use frozen ones).

Unknown values are NaN (floats) or None, never 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from hdeem_watch.tui.downsample import Columns

#: Baseline origins that are a true idle for every channel kind (see ChannelView.baseline_is_idle).
IDLE_ORIGINS = ("quiet", "measured")
#: Connection states shown in the health bar.
CONNECTION_STATES = ("connecting", "live", "stale", "reconnecting", "paused")


@dataclass(frozen=True)
class CommandRates:
    """The DRAM commands behind one power channel, from the memory-controller counters (the
    ``counters`` topic, summed over the IMC channels the sensor measures).

    Attributes:
        act_per_s: activates per second.
        rd_per_s: read CASes per second.
        wr_per_s: write CASes per second.
        powerdown_share: share of the time the ranks spent in power-down (0..1; NaN unknown).
    """

    act_per_s: float
    rd_per_s: float
    wr_per_s: float
    powerdown_share: float


@dataclass(frozen=True, eq=False)
class ChannelView:
    """One channel of one node.

    Attributes:
        name: channel name (``DDR_AB``, ``CPU0``, ``BLADE``, ...).
        kind: ``dram``, ``cpu``, ``blade`` or ``other``.
        rate_hz: native sample rate (NaN if not yet known).
        power_w: current value (mean of the last half second of samples; NaN if none).
        baseline_w: idle baseline (NaN if none yet).
        spread_w: the baseline's spread (NaN if none).
        baseline_origin: ``idle-run``, ``quiet`` or ``""``.
        energy_j: cumulative energy reported by the daemon (NaN if unknown).
        status: the daemon's channel status (``ok``, ``stale``, ...).
        source_gaps: gaps the daemon counted at the sensor.
        columns: the plot envelope of the time window (None when not computed).
        commands: its DRAM command rates from the counters (None without counters).
    """

    name: str
    kind: str
    rate_hz: float
    power_w: float
    baseline_w: float
    spread_w: float
    baseline_origin: str
    energy_j: float
    status: str
    source_gaps: int
    columns: Columns | None = None
    commands: CommandRates | None = None

    @property
    def baseline_is_idle(self) -> bool:
        """Whether the baseline is this channel's true idle power.

        A DRAM channel is idle during an idle run (no memory traffic). A CPU, blade or other
        channel is not: the idle kernel keeps its threads spinning, and ``baseline.measure`` is
        reported with the same origin (``idle-run``). Only a ``quiet`` baseline (the quietest
        stretch while no run was going on) or a ``measured`` one (``baseline.measure``, should the
        daemon name it apart) is their idle.
        """
        return self.kind == "dram" or self.baseline_origin in IDLE_ORIGINS

    @property
    def above_w(self) -> float:
        """Power above the idle baseline (NaN when either is unknown, or when the baseline is not
        a true idle: see :attr:`baseline_is_idle`)."""
        return self.power_w - self.baseline_w if self.baseline_is_idle else math.nan


@dataclass(frozen=True)
class RunView:
    """One benchmark run (finished or in progress).

    Attributes:
        run_id: the daemon's run id.
        name: run name.
        kernel: kernel name (``idle`` for an idle run).
        threads: thread count (0 if unknown).
        duration_s: measured window (elapsed so far while running).
        measured_j: measured DRAM energy over the window (NaN while running or unknown).
        model_datasheet_j: the model's energy with datasheet currents.
        model_calibrated_j: the model's energy with the calibration of the time.
        running: True for the run in progress.
        simulated: the run was on a simulated node.
        history: the daemon had it stored before the UI connected (not a new run to the user).
    """

    run_id: str
    name: str
    kernel: str
    threads: int
    duration_s: float
    measured_j: float
    model_datasheet_j: float
    model_calibrated_j: float
    running: bool = False
    simulated: bool = False
    history: bool = False

    @property
    def error_datasheet(self) -> float:
        """Relative error of the datasheet model against the measurement (NaN if unknown)."""
        return _rel(self.model_datasheet_j, self.measured_j)

    @property
    def error_calibrated(self) -> float:
        """Relative error of the calibrated model against the measurement (NaN if unknown)."""
        return _rel(self.model_calibrated_j, self.measured_j)


def _rel(model: float, measured: float) -> float:
    if not (math.isfinite(model) and math.isfinite(measured)) or measured == 0:
        return math.nan
    return (model - measured) / measured


@dataclass(frozen=True)
class CurrentView:
    """One calibrated current.

    Attributes:
        name: current name (``idd0``, ...).
        datasheet_a: datasheet value.
        calibrated_a: fitted value (NaN before the first fit).
        ci95_a: half-width of its 95 % interval (NaN if unknown).
        identifiable: whether the runs so far determine it.
        truth_a: the simulation's hidden value (NaN off the simulator).
        history_a: the fitted value over time (oldest first), for the aging sparkline.
    """

    name: str
    datasheet_a: float
    calibrated_a: float
    ci95_a: float
    identifiable: bool
    truth_a: float = math.nan
    history_a: tuple[float, ...] = ()


@dataclass(frozen=True)
class AlarmView:
    """A drift alarm of a sensor group (``DriftAlarm.to_dict()`` of the ``calib`` body).

    Attributes:
        group: the sensor group (``DDR_CD``, ``DRAM1``, ``node``).
        current: the current concerned (``energy``: the group's energy as a whole).
        kind: ``residual-cusum`` or ``sibling``.
        direction: ``up`` or ``down``.
        statistic: what crossed ``threshold``.
        threshold: the alarm threshold.
        time_ns: time of the run that raised it.
    """

    group: str
    current: str
    kind: str
    direction: str
    statistic: float
    threshold: float
    time_ns: int

    @property
    def key(self) -> tuple[str, str, str, int]:
        """Identity of the alarm (to print each once)."""
        return (self.group, self.current, self.kind, self.time_ns)


@dataclass(frozen=True)
class GroupFitView:
    """The fit of one sensor group (a DIMM pair, a RAPL socket, or ``node``: the groups' sum).

    Attributes:
        name: the group.
        currents: its currents (datasheet, calibrated, interval), in the fit's order.
        runs: runs in its fit.
        status: the fit's status (``ok``, ``at-bound``, ``underdetermined``, ...; "" without a fit).
        error_loo: its leave-one-out error (NaN if unknown).
        dimms: DIMMs behind the sensor (0 for ``node``).
        alarms: its drift alarms, oldest first.
    """

    name: str
    currents: tuple[CurrentView, ...] = ()
    runs: int = 0
    status: str = ""
    error_loo: float = math.nan
    dimms: int = 0
    alarms: tuple[AlarmView, ...] = ()


@dataclass(frozen=True)
class CalibView:
    """The node's calibration state.

    Attributes:
        currents: per current, in the fit's order.
        error_before: mean relative error with datasheet currents.
        error_after: mean relative error after the fit.
        error_loo: leave-one-out error.
        n_runs: runs in the fit.
        determined: the fit has more runs than unknowns (before that, its errors mean nothing:
            an exact fit through every point has "after 0 %" and a wild leave-one-out).
        suggested_next: the run the calibrator suggests next ("" if none).
        simulated: the truth values come from the simulator.
        model_error: why the daemon cannot model runs, if it cannot ("" otherwise).
        groups: the per-sensor-group fits (the pairs, then ``node``; empty from a daemon without them).
        alarms: the groups' drift alarms, oldest first.
    """

    currents: tuple[CurrentView, ...] = ()
    error_before: float = math.nan
    error_after: float = math.nan
    error_loo: float = math.nan
    n_runs: int = 0
    determined: bool = True
    suggested_next: str = ""
    simulated: bool = False
    model_error: str = ""
    groups: tuple[GroupFitView, ...] = ()
    alarms: tuple[AlarmView, ...] = ()


@dataclass(frozen=True)
class HealthView:
    """Connection and daemon health.

    Attributes:
        state: one of :data:`CONNECTION_STATES`.
        endpoint: the control endpoint.
        detail: a short reason (the last error, "daemon restarted", ...).
        last_rx_age_s: seconds since the last message (NaN if none yet).
        gaps: messages missed on the wire (from sequence numbers).
        restarts: daemon restarts seen.
        source_kind: ``sim``, ``hdeem``, ``rapl``, ``replay`` ("" if unknown).
        source_health: the source's own health string.
        cpu_percent: the daemon's CPU share (NaN if unknown).
        rss_bytes: the daemon's resident memory (0 if unknown).
        uptime_s: the daemon's uptime (NaN if unknown).
        notice: the last control result or error to show the user.
    """

    state: str
    endpoint: str
    detail: str = ""
    last_rx_age_s: float = math.nan
    gaps: int = 0
    restarts: int = 0
    source_kind: str = ""
    source_health: str = ""
    cpu_percent: float = math.nan
    rss_bytes: int = 0
    uptime_s: float = math.nan
    notice: str = ""


@dataclass(frozen=True)
class JobView:
    """A SLURM job open on the node (the daemon measures its window).

    Attributes:
        job_id: SLURM's job id.
        user: its user ("" if unknown).
        elapsed_s: seconds since it started (NaN if unknown).
    """

    job_id: str
    user: str = ""
    elapsed_s: float = math.nan


def jobs_line(jobs: tuple[JobView, ...]) -> str:
    """The UI's current-job line ("" when no job is open).

    >>> jobs_line((JobView("4242", "alice", 3723.0),))
    ' job 4242 (alice) 1:02:03'
    """
    if not jobs:
        return ""
    parts = []
    for job in jobs:
        elapsed = job.elapsed_s
        clock = "–" if not math.isfinite(elapsed) else \
            f"{int(elapsed) // 3600}:{int(elapsed) // 60 % 60:02d}:{int(elapsed) % 60:02d}"
        parts.append(f"{job.job_id} ({job.user or '?'}) {clock}")
    return f" {'job' if len(jobs) == 1 else 'jobs'} " + " · ".join(parts)


@dataclass(frozen=True)
class NodeSnapshot:
    """Everything the UI shows about one node at one instant.

    Attributes:
        node: node name ("?" before the first status).
        built_mono_ns: monotonic time the snapshot was built (the app flags an old one).
        window_s: the plot's time window.
        channels: channels in display order.
        runs: finished runs, newest last (only the newest few: see ``runs_total``).
        runs_total: how many runs the daemon has finished in all (0 if unknown).
        current_run: the run in progress, if any.
        jobs: the SLURM jobs open on the node.
        calib: calibration state.
        health: connection and daemon health.
    """

    node: str
    built_mono_ns: int
    window_s: float
    channels: tuple[ChannelView, ...] = ()
    runs: tuple[RunView, ...] = ()
    runs_total: int = 0
    current_run: RunView | None = None
    jobs: tuple[JobView, ...] = ()
    calib: CalibView = field(default_factory=CalibView)
    health: HealthView = field(default_factory=lambda: HealthView(state="connecting", endpoint=""))
