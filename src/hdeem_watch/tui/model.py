"""The UI's state of one node, fed with wire-protocol messages, read as immutable snapshots.

:class:`NodeModel` is the pure core of the TUI: it keeps per-channel ring buffers of samples, the
latest baselines, runs and calibration, counts sequence gaps and restarts, and turns all of that
into a :class:`~hdeem_watch.tui.snapshot.NodeSnapshot` on request (downsampling each channel onto
the plot's columns with its min/max envelope). It does no I/O and reads no clock: every method
takes the times it needs, so tests drive it without sockets or an event loop.

Example:
    >>> from hdeem_watch.wire import protocol
    >>> import numpy as np
    >>> m = NodeModel(endpoint="ipc:///x")
    >>> frames = protocol.encode_samples("n1", "DDR_AB", seq=0, rate_hz=100.0,
    ...     t_wall_ns=np.array([0, 10_000_000]), power_w=np.array([5.0, 7.0]),
    ...     energy_j=1.0, status="ok", t_ns=10_000_000)
    >>> m.apply(protocol.decode(frames), recv_mono_ns=0)
    >>> snap = m.snapshot(now_mono_ns=0, now_wall_ns=20_000_000, window_s=1.0, width=4)
    >>> snap.channels[0].name, snap.channels[0].power_w
    ('DDR_AB', 6.0)
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from hdeem_watch.job_record import JobRecord
from hdeem_watch.run_record import RunRecord
from hdeem_watch.tui.downsample import ColumnCache
from hdeem_watch.tui.recent_samples import RecentSamples
from hdeem_watch.tui.records import calib_view, job_record, num, run_record, run_view, sensor_command_rates
from hdeem_watch.tui.snapshot import (
    CalibView,
    ChannelView,
    CommandRates,
    HealthView,
    JobView,
    NodeSnapshot,
    RunView,
)
from hdeem_watch.wire.protocol import GapTracker, Message

#: Display order of the HDEEM channels; others follow alphabetically.
CHANNEL_ORDER = ("DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH", "CPU0", "CPU1", "BLADE")
#: A node with no message for this long is stale (the daemon sends a heartbeat every second).
STALE_AFTER_S = 3.0
#: The "current value" is the mean over this trailing span of samples.
CURRENT_SPAN_NS = 500_000_000
#: Two status messages whose implied daemon start times differ by more than this are two daemons.
BOOT_TOLERANCE_S = 1.0
#: How many finished runs to keep.
MAX_RUNS = 200


def channel_kind(name: str) -> str:
    """``dram``, ``cpu``, ``blade`` or ``other`` from an HDEEM-style channel name."""
    upper = name.upper()
    if upper.startswith(("DDR", "DRAM")):
        return "dram"
    if upper.startswith("CPU") or upper.startswith("PKG"):
        return "cpu"
    if upper.startswith("BLADE"):
        return "blade"
    return "other"


def _order_key(name: str) -> tuple[int, str]:
    return (CHANNEL_ORDER.index(name), name) if name in CHANNEL_ORDER else (len(CHANNEL_ORDER), name)


class _Channel:
    """Mutable per-channel state inside :class:`NodeModel`."""

    def __init__(self, name: str, rate_hz: float, max_window_s: float) -> None:
        self.name = name
        self.rate_hz = rate_hz
        self.ring = RecentSamples(int(max(rate_hz, 1.0) * max_window_s) + 64)
        self.energy_j = math.nan
        self.status = "?"
        self.source_gaps = 0
        self.status_power_w = math.nan
        self.columns = ColumnCache()


class NodeModel:
    """State of one node as seen on the wire (not thread-safe: owned by one feed thread).

    Args:
        endpoint: the daemon's control endpoint (shown in the health bar).
        max_window_s: the longest plot window; each channel keeps that many seconds of samples.
        stale_after_s: silence after which the node is shown stale.
    """

    def __init__(self, endpoint: str, *, max_window_s: float = 600.0, stale_after_s: float = STALE_AFTER_S) -> None:
        self.endpoint = endpoint
        self.max_window_s = max_window_s
        self.stale_after_s = stale_after_s
        self.node = "?"
        self._sequences = GapTracker(silence_ns=int(stale_after_s * 1e9))
        self.connection = "connecting"
        self.detail = ""
        self.notice = ""
        self.last_rx_mono_ns: int | None = None
        self._channels: dict[str, _Channel] = {}
        self._status: Mapping[str, Any] = {}
        self._baselines: dict[str, Mapping[str, Any]] = {}
        self._runs: dict[str, RunRecord] = {}
        self._history_ids: set[str] = set()
        self._stored_runs: int | None = None  # the daemon's count at the last status reply
        self._runs_since_status = 0
        self._current_run: RunRecord | None = None
        self._jobs: dict[str, JobRecord] = {}  # open SLURM jobs by id
        self._calib_body: Mapping[str, Any] = {}
        self._calib_cache: tuple[int, CalibView] | None = None
        self._calib_version = 0
        self._boot_s = math.nan
        #: Command rates per DRAM channel from the ``counters`` topic, and when they came (monotonic ns).
        self._commands: dict[str, CommandRates] = {}
        self._commands_mono_ns = 0

    # ------------------------------------------------------------------ feeding

    def _channel(self, name: str, rate_hz: float) -> _Channel:
        channel = self._channels.get(name)
        if channel is None:
            channel = _Channel(name, rate_hz if math.isfinite(rate_hz) else 100.0, self.max_window_s)
            self._channels[name] = channel
        return channel

    def apply(self, msg: Message, recv_mono_ns: int) -> None:
        """Take one decoded stream message received at ``recv_mono_ns`` (monotonic)."""
        self.last_rx_mono_ns = recv_mono_ns
        if self.connection in ("connecting", "stale", "reconnecting"):
            self.connection = "live"
        self.node = msg.node
        restarts = self._sequences.restarts
        self._sequences.observe(msg.topic, msg.seq, recv_mono_ns)
        if self._sequences.restarts != restarts:
            self._restarted()
        header = msg.header
        if msg.kind == "samples" and msg.channel is not None:
            channel = self._channel(msg.channel, num(header.get("rate_hz")))
            t_ns, power_w = msg.samples()
            channel.ring.extend(t_ns, power_w)
            channel.energy_j = num(header.get("energy_j"))
            channel.status = str(header.get("status", "?"))
        elif msg.kind == "status":
            self.apply_status(header)
        elif msg.kind == "run":
            self.apply_run_event(header)
        elif msg.kind == "calib":
            self.apply_calib(header)
        elif msg.kind == "baseline":
            self.apply_baselines(header)
        elif msg.kind == "counters":
            self._commands = sensor_command_rates(header)
            self._commands_mono_ns = recv_mono_ns
        elif msg.kind == "job":
            self.apply_job_event(header)

    @property
    def gaps(self) -> int:
        """Stream messages missed (sequence jumps; :class:`~hdeem_watch.wire.protocol.GapTracker`)."""
        return self._sequences.missed

    @property
    def restarts(self) -> int:
        """Daemon restarts seen (a sequence going back, or a new start time in the status)."""
        return self._sequences.restarts

    def _restarted(self) -> None:
        """A new daemon instance (counted by the gap tracker): say so and forget its start time."""
        self.detail = "daemon restarted"
        self._boot_s = math.nan

    def apply_status(self, body: Mapping[str, Any], wall_ns: int | None = None) -> None:
        """Take a status heartbeat (or the ``status`` control result received at ``wall_ns``).

        The daemon's start time (wall clock minus uptime) tells a restart even when no sequence
        number went backwards (the first messages of the new daemon were missed).
        """
        uptime = num(body.get("uptime_s"))
        t_ns = num(body.get("t_ns")) if body.get("t_ns") is not None else num(wall_ns)
        if math.isfinite(uptime) and math.isfinite(t_ns):
            boot_s = t_ns / 1e9 - uptime
            if math.isfinite(self._boot_s) and abs(boot_s - self._boot_s) > BOOT_TOLERANCE_S:
                self._sequences.restart()
                self._restarted()
            self._boot_s = boot_s
        if isinstance(body.get("node"), str):
            self.node = body["node"]
        self._status = body
        channels = body.get("channels")
        if isinstance(channels, Mapping):
            for name, info in channels.items():
                if not isinstance(info, Mapping):
                    continue
                channel = self._channel(str(name), num(info.get("rate_hz", info.get("nominal_hz"))))
                gaps = num(info.get("gaps"))
                channel.source_gaps = int(gaps) if math.isfinite(gaps) else channel.source_gaps
                channel.status = str(info.get("status", channel.status))
                channel.status_power_w = num(info.get("power_w"))
        if "run" in body:
            self._current_run = run_record(body.get("run"))
        jobs = body.get("jobs")  # the status reply lists the open jobs (the heartbeat does not)
        if isinstance(jobs, list):
            self._jobs = {j.job_id: j for j in map(job_record, jobs) if j is not None}
        stored = body.get("runs")  # the status reply counts the stored runs (the heartbeat does not)
        if isinstance(stored, int) and not isinstance(stored, bool):
            self._stored_runs = stored
            self._runs_since_status = 0

    def apply_job_event(self, body: Mapping[str, Any]) -> None:
        """Take a ``job`` message: ``{"event": "start"|"stop", "job": {...}}``."""
        job = job_record(body.get("job"))
        if job is None:
            return
        if body.get("event") == "start":
            self._jobs[job.job_id] = job
        else:
            self._jobs.pop(job.job_id, None)

    def apply_run_event(self, body: Mapping[str, Any]) -> None:
        """Take a ``run`` message: ``{"event": "start"|"stop", "run": {...}}``."""
        run = run_record(body.get("run"))
        if run is None:
            return
        if body.get("event") == "start":
            self._current_run = run
        else:
            if run.run_id not in self._runs:
                self._runs_since_status += 1
            self._add_run(run, history=False)
            if self._current_run is not None and self._current_run.run_id == run.run_id:
                self._current_run = None

    def add_runs(self, runs: list[Any], *, history: bool = False) -> None:
        """Add finished run records, oldest first (from the ``run`` topic or ``runs.list``).

        ``history``: runs the daemon had stored before this UI connected (not new to the user).
        """
        for value in runs:
            run = run_record(value)
            if run is not None:
                self._add_run(run, history=history)

    def _add_run(self, run: RunRecord, *, history: bool) -> None:
        if run.run_id not in self._runs and history:
            self._history_ids.add(run.run_id)
        self._runs[run.run_id] = run
        while len(self._runs) > MAX_RUNS:
            self._history_ids.discard(next(iter(self._runs)))
            self._runs.pop(next(iter(self._runs)))

    def runs_total(self) -> int:
        """Finished runs of the daemon: its stored count at the last status reply plus the runs
        finished since, else the runs this model holds (the snapshot carries only the newest)."""
        if self._stored_runs is None:
            return len(self._runs)
        return max(len(self._runs), self._stored_runs + self._runs_since_status)

    def apply_calib(self, body: Mapping[str, Any]) -> None:
        """Take a ``calib`` message body or the ``calib.get`` result."""
        self._calib_body = body
        self._calib_version += 1

    def apply_baselines(self, body: Mapping[str, Any]) -> None:
        """Take a ``baseline`` message body or the ``baseline.get`` result."""
        channels = body.get("channels", body)
        if isinstance(channels, Mapping):
            for name, info in channels.items():
                if isinstance(info, Mapping):
                    self._baselines[str(name)] = info

    def set_connection(self, state: str, detail: str = "") -> None:
        """Record a connection state decided by the feed (``connecting``, ``reconnecting``, ...)."""
        self.connection = state
        if detail:
            self.detail = detail

    # ------------------------------------------------------------------ reading

    def health(self, now_mono_ns: int) -> HealthView:
        """The connection/health view at ``now_mono_ns``."""
        age = math.nan if self.last_rx_mono_ns is None else (now_mono_ns - self.last_rx_mono_ns) / 1e9
        state = self.connection
        if state == "live" and (not math.isfinite(age) or age > self.stale_after_s):
            state = "stale"
        source = self._status.get("source") if isinstance(self._status.get("source"), Mapping) else {}
        process = self._status.get("process") if isinstance(self._status.get("process"), Mapping) else {}
        assert isinstance(source, Mapping) and isinstance(process, Mapping)
        rss = num(process.get("rss_bytes"))
        return HealthView(
            state=state,
            endpoint=self.endpoint,
            detail=self.detail,
            last_rx_age_s=age,
            gaps=self.gaps,
            restarts=self.restarts,
            source_kind=str(source.get("kind", "")),
            source_health=str(source.get("health", "")),
            cpu_percent=num(process.get("cpu_percent")),
            rss_bytes=int(rss) if math.isfinite(rss) else 0,
            uptime_s=num(self._status.get("uptime_s")),
            notice=self.notice,
        )

    def _calib(self) -> CalibView:
        if self._calib_cache is None or self._calib_cache[0] != self._calib_version:
            self._calib_cache = (self._calib_version, calib_view(self._calib_body))
        return self._calib_cache[1]

    def _channel_view(self, channel: _Channel, t0_ns: int, t1_ns: int, width: int | None) -> ChannelView:
        newest = channel.ring.newest_t_ns()
        power = math.nan
        columns = None
        if newest is not None:
            _, recent = channel.ring.window(newest - CURRENT_SPAN_NS, newest + 1)
            finite = recent[np.isfinite(recent)]
            power = float(finite.mean()) if len(finite) else math.nan
        if width is not None:
            columns = channel.columns.columns(
                channel.ring.window, t1_ns=t1_ns, window_ns=t1_ns - t0_ns, width=width, newest_ns=newest
            )
        baseline = self._baselines.get(channel.name, {})
        return ChannelView(
            name=channel.name,
            kind=channel_kind(channel.name),
            rate_hz=channel.rate_hz,
            power_w=power,
            baseline_w=num(baseline.get("power_w")),
            spread_w=num(baseline.get("spread_w")),
            baseline_origin=str(baseline.get("origin", "")),
            energy_j=channel.energy_j,
            status=channel.status,
            source_gaps=channel.source_gaps,
            columns=columns,
            commands=self._commands.get(channel.name)
            if self.last_rx_mono_ns is not None
            and self.last_rx_mono_ns - self._commands_mono_ns <= self.stale_after_s * 1e9 else None,
        )

    def window_end_ns(self, now_wall_ns: int) -> int:
        """The right edge of the plot: the newest sample if recent or ahead of this clock (a sped-up
        simulated node, a daemon host whose clock runs ahead), else now (so a silent node scrolls away)."""
        newest = max((c.ring.newest_t_ns() or 0 for c in self._channels.values()), default=0)
        if newest and now_wall_ns - newest < self.stale_after_s * 1e9:
            return newest + 1
        return now_wall_ns

    def snapshot(
        self,
        *,
        now_mono_ns: int,
        now_wall_ns: int,
        window_s: float,
        width: int | None,
        max_runs: int = 50,
    ) -> NodeSnapshot:
        """An immutable snapshot; ``width`` plot columns per channel (None: no plot data)."""
        t1 = self.window_end_ns(now_wall_ns)
        t0 = t1 - int(window_s * 1e9)
        channels = tuple(
            self._channel_view(self._channels[name], t0, t1, width)
            for name in sorted(self._channels, key=_order_key)
        )
        runs = tuple(
            run_view(record, history=key in self._history_ids)
            for key, record in list(self._runs.items())[-max_runs:]
        )
        current: RunView | None = None
        if self._current_run is not None:
            started = self._current_run.t_start_ns
            elapsed = (now_wall_ns - started) / 1e9 if started is not None else math.nan
            current = run_view(self._current_run, running=True, elapsed_s=elapsed)
        jobs = tuple(JobView(job_id=key, user=job.user,
                             elapsed_s=(now_wall_ns - job.t_start_ns) / 1e9 if job.t_start_ns is not None else math.nan)
                     for key, job in self._jobs.items())
        return NodeSnapshot(
            node=self.node,
            built_mono_ns=now_mono_ns,
            window_s=window_s,
            channels=channels,
            runs=runs,
            runs_total=max(self.runs_total(), len(runs)),
            current_run=current,
            jobs=jobs,
            calib=self._calib(),
            health=self.health(now_mono_ns),
        )
