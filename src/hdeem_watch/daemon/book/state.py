"""The run book of one node: channels, runs, windows and baselines — a pure core without I/O.

:class:`NodeState` takes the source's batches (:meth:`NodeState.on_batch`), opens and closes run
and idle windows (:meth:`start_run`, :meth:`stop_run`, :meth:`measure_baseline`), and returns the
windows that closed as typed :class:`ClosedWindow` values: the finished :class:`RunRecord` and the
baselines found. It owns no socket, file or thread and reads time only from its injected monotonic
and wall clocks, so a run's whole life is testable with a fake clock and fake batches. The daemon
(:mod:`hdeem_watch.daemon.service`) is the shell that polls the source, publishes, stores and
models what this core decides.

Example:
    >>> import numpy as np
    >>> from hdeem_watch.sources.base import ChannelInfo, SourceBatch
    >>> now = [0]
    >>> book = NodeState([ChannelInfo("DDR_AB", 100.0, "dram")], node="n1",
    ...                  monotonic=lambda: now[0], wall=lambda: now[0])
    >>> def batch(k):  # the k-th 10 ms sample of 2 W
    ...     t = np.array([k * 10_000_000])
    ...     return SourceBatch(t[0], t[0], {"DDR_AB": (t, np.array([2.0]))}, {"DDR_AB": 0.02 * k},
    ...                        {"DDR_AB": "ok"})
    >>> _ = book.on_batch(batch(1))
    >>> run = book.start_run(parse_run_args({"kernel": "idle"}))
    >>> for k in range(2, 102):
    ...     now[0] = k * 10_000_000
    ...     _ = book.on_batch(batch(k))
    >>> _ = book.stop_run(run.run_id)
    >>> now[0] = 1_020_000_000
    >>> closed = book.on_batch(batch(102)).closed
    >>> closed[0].run.state, round(closed[0].run.dram_energy_j, 6), closed[0].run.window_s
    ('modelling', 2.0, 1.0)
"""

from __future__ import annotations

import collections
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

from hdeem_watch.daemon.book import baselines as bl
from hdeem_watch.daemon.book.channels import ChannelAccount
from hdeem_watch.daemon.book.runs import RunArgs, RunLimits, parse_run_args, started_run
from hdeem_watch.daemon.book.windows import Window, WindowKind
from hdeem_watch.run_record import RunRecord
from hdeem_watch.sources.base import ChannelInfo, SourceBatch

__all__ = ["BatchOutcome", "ClosedWindow", "Conflict", "NodeState", "parse_run_args"]

Clock = Callable[[], int]

#: How long a closing window waits for lagging samples (monotonic seconds) before it closes anyway.
CLOSE_GRACE_S = 3.0
#: Longest ``baseline.measure`` window in seconds (it blocks ``run.start`` while it lasts).
MAX_BASELINE_S = 600.0


class Conflict(Exception):
    """The node is busy with another window (a run or an idle measurement)."""


@dataclass(frozen=True)
class ClosedWindow:
    """A window that closed.

    Attributes:
        kind: ``"run"``, ``"baseline"`` or ``"job"``.
        window_s: its duration on the source's clock.
        run: the finished run (state ``modelling``, or ``aborted``) for a run window.
        window: the closed window itself (a job window: its id, peaks and sample spans).
        energy_j: what a job window measured per channel (J).
        baselines: the idle baselines it measured, by channel (channels without samples have none).
        kept: the channels whose stored baseline it replaced.
        cancelled: a ``baseline.cancel`` ended it (nothing measured).
    """

    kind: WindowKind
    window_s: float
    run: RunRecord | None = None
    baselines: dict[str, bl.Baseline] = field(default_factory=dict)
    kept: dict[str, bl.Baseline] = field(default_factory=dict)
    cancelled: bool = False
    window: Window | None = None
    energy_j: dict[str, float] = field(default_factory=dict)


class BatchOutcome(NamedTuple):
    """What one batch did: the channels with news to publish and the windows it closed."""

    fresh: list[str]
    closed: list[ClosedWindow]


class NodeState:
    """Channels, runs, windows and baselines of one node.

    Args:
        channels: the source's channels.
        node: the node's name (in run records).
        monotonic: monotonic clock (ns) — the same clock the source stamps ``t_mono_ns`` with.
        wall: wall clock (ns), for record labels only.
        speed: source seconds per monotonic second (read from the source once, at open).
        poll_interval_s: the fast poll period (bounds the close grace).
        history_s: recent samples kept per DRAM channel for quiet periods.
        next_seq: the number of the next run id (``r<n>``; continue the stored ones).
        baselines: the stored baselines.
        limits: bounds of ``run.start``'s numbers.
        paced: the source publishes one sample per read (:class:`~hdeem_watch.sources.base.QuietLimit`):
            no missing samples are counted between reads.
    """

    def __init__(self, channels: Sequence[ChannelInfo], *, node: str, monotonic: Clock, wall: Clock,
                 speed: float = 1.0, poll_interval_s: float = 0.04, history_s: float = 60.0, next_seq: int = 1,
                 baselines: Mapping[str, bl.Baseline] | None = None, limits: RunLimits | None = None,
                 paced: bool = False) -> None:
        self.node = node
        self.monotonic = monotonic
        self.wall = wall
        self.speed = float(speed)
        self.poll_interval_s = float(poll_interval_s)
        self.limits = limits
        self.accounts = {i.name: ChannelAccount(i.name, i.rate_hz, i.kind, history_s=history_s, paced=paced)
                         for i in channels}
        self.dram_channels = tuple(i.name for i in channels if i.kind == "dram")
        self.windows: list[Window] = []
        self.baselines: dict[str, bl.Baseline] = dict(baselines or {})
        self.next_seq = int(next_seq)
        self.runs_finished = 0
        self.polls = 0
        #: The last poll failure (None once a heartbeat saw no failure since the previous one).
        self.poll_error: str | None = None
        self._failed_since_heartbeat = False
        self._offsets: collections.deque[int] = collections.deque(maxlen=400)

    # -- batches ----------------------------------------------------------------------------------

    def on_batch(self, batch: SourceBatch) -> BatchOutcome:
        """Account one batch, feed the open windows, close the ready ones.

        The daemon's hot path (25 times a second): locals instead of attribute look-ups.
        """
        self.polls += 1
        windows = self.windows
        keep_history = not any(w.kind == "run" for w in windows)
        accounts, energies, statuses, gaps = self.accounts, batch.energy_j, batch.status, batch.gaps
        fresh: list[str] = []
        nan = math.nan
        for name, (t_ns, power_w) in batch.samples.items():
            account = accounts.get(name)
            if account is None:
                continue
            energy = energies.get(name, nan)
            news = account.take(t_ns, power_w, energy, statuses.get(name, "ok"),
                                int(gaps.get(name, 0)) if gaps else 0, keep_history)
            for window in windows:
                window.observe(name, t_ns, power_w, energy_j=energy)
            if news:
                fresh.append(name)
        speed = self.speed
        self._offsets.append(batch.t_wall_ns - (batch.t_mono_ns if speed == 1.0 else round(batch.t_mono_ns * speed)))
        return BatchOutcome(fresh, self.close_ready() if windows else [])

    def on_poll_error(self, error: BaseException) -> str:
        """A failed poll: every channel's status and the source health say so; returns the message."""
        self.polls += 1
        message = f"error: {type(error).__name__}: {error}"
        self.poll_error = message
        self._failed_since_heartbeat = True
        for account in self.accounts.values():
            account.status = message
        return message

    def heartbeat(self) -> None:
        """Close the rate windows; a poll error seen in no poll since the last heartbeat is cleared."""
        for account in self.accounts.values():
            account.close_rate_window()
        if not self._failed_since_heartbeat:
            self.poll_error = None
        self._failed_since_heartbeat = False

    # -- the channels now -------------------------------------------------------------------------

    def newest_dram_sample_ns(self) -> int | None:
        """The time of the newest sample of any DRAM channel (None before the first)."""
        last = [t for c in self.dram_channels if (t := self.accounts[c].last_t_ns) is not None]
        return max(last) if last else None

    def energies(self) -> dict[str, float]:
        """The cumulative energy of every channel."""
        return {name: a.energy_j for name, a in self.accounts.items()}

    def last_sample_times(self) -> dict[str, int | None]:
        """The last sample time of every channel."""
        return {name: a.last_t_ns for name, a in self.accounts.items()}

    def rates(self) -> dict[str, float]:
        """The nominal rate of every channel."""
        return {name: a.rate_hz for name, a in self.accounts.items()}

    def sample_time_of(self, t_mono_ns: int) -> int:
        """A monotonic instant on the source's sample-time axis (wall ns; the sim's own time).

        From the recent batches' ``t_wall_ns − t_mono_ns × speed``: a source that lags (holds its
        samples back for a while) only lowers that offset, so the largest recent one is the true
        mapping.
        """
        if not self._offsets:
            return self.wall()
        return round(int(t_mono_ns) * self.speed) + max(self._offsets)

    # -- runs -------------------------------------------------------------------------------------

    def exclusive_windows(self) -> list[Window]:
        """The open run and idle windows (a job window runs beside them and blocks nothing)."""
        return [w for w in self.windows if w.kind != "job"]

    def running(self) -> RunRecord | None:
        """The run in progress (its window still open or closing), if any."""
        return next((w.run for w in self.windows if w.run is not None), None)

    def ensure_free(self) -> None:
        """Raise :class:`Conflict` when a run or idle window is open."""
        for window in self.exclusive_windows():
            if window.run is not None:
                raise Conflict(f"run {window.run.run_id} is in progress; stop it first")
            raise Conflict("an idle baseline measurement is in progress (baseline.cancel ends it)")

    def start_run(self, args: RunArgs) -> RunRecord:
        """Open a run window now (poll the source just before, for a tight start).

        Raises:
            Conflict: another window is open.
        """
        self.ensure_free()
        now = self.monotonic()
        record = started_run(f"r{self.next_seq}", args, t_wall_ns=self.wall(), node=self.node)
        self.next_seq += 1
        self.windows.append(self._open("run", now, run=record))
        for account in self.accounts.values():
            if account.history is not None:
                account.history.clear()
        return record

    def stop_run(self, run_id: str, *, abort: bool = False) -> Window | None:
        """Ask the run's window to close now (poll just before); None when that run is not in progress.

        The stop lands on the source's sample-time axis; the window closes once every DRAM channel
        has delivered its samples up to it (a sensor may lag: the sim while it plans a run), or at
        a deadline. A second stop of a closing run changes nothing.
        """
        window = next((w for w in self.windows if w.run is not None and w.run.run_id == run_id), None)
        if window is None or window.closing:
            return window
        now = self.monotonic()
        window.abort = abort
        window.request_close(target_t_ns=self.sample_time_of(now), deadline_mono_ns=self._close_deadline(now),
                             rates_hz=self.rates(), last_t_ns=self.last_sample_times(), energy_j=self.energies())
        return window

    def measure_baseline(self, seconds: float) -> Window:
        """Open an idle window of ``seconds`` (source time), closing by itself.

        Raises:
            Conflict: another window is open.
            ValueError: ``seconds`` not in (0, :data:`MAX_BASELINE_S`].
        """
        if isinstance(seconds, bool) or not isinstance(seconds, int | float) or not 0 < seconds <= MAX_BASELINE_S:
            raise ValueError(f"args.seconds = {seconds!r}: expected a duration in (0, {MAX_BASELINE_S:g}] s")
        self.ensure_free()
        now = self.monotonic()
        window = self._open("baseline", now)
        newest = self.newest_dram_sample_ns()
        start = newest if newest is not None else self.sample_time_of(now)
        window.request_close(target_t_ns=start + round(seconds * 1e9),
                             deadline_mono_ns=self._close_deadline(now, seconds / self.speed), rates_hz=self.rates())
        self.windows.append(window)
        return window

    def cancel_baseline(self) -> ClosedWindow | None:
        """End the idle measurement in progress without a result (None when there is none)."""
        window = next((w for w in self.windows if w.kind == "baseline"), None)
        if window is None:
            return None
        self.windows.remove(window)
        return ClosedWindow(kind="baseline", window_s=(self.monotonic() - window.t_start_mono_ns) / 1e9 * self.speed,
                            cancelled=True)

    def _open(self, kind: WindowKind, now: int, run: RunRecord | None = None, job_id: str | None = None) -> Window:
        return Window(kind=kind, start_energy_j=self.energies(), start_t_ns=self.last_sample_times(),
                      dram_channels=self.dram_channels, t_start_mono_ns=now, run=run, job_id=job_id,
                      keep_samples=kind != "job")

    # -- jobs (the bookkeeping of jobs is daemon/jobs/book.py's) -----------------------------------

    def open_job_window(self, job_id: str) -> Window:
        """Open a job's window now (poll the source just before); it blocks no run or baseline."""
        window = self._open("job", self.monotonic(), job_id=job_id)
        self.windows.append(window)
        return window

    def close_job_window(self, window: Window) -> None:
        """Ask a job's window to close now (poll just before), cut to the sample like a run's."""
        if window.closing:
            return
        now = self.monotonic()
        window.request_close(target_t_ns=self.sample_time_of(now), deadline_mono_ns=self._close_deadline(now),
                             rates_hz=self.rates(), last_t_ns=self.last_sample_times(), energy_j=self.energies())

    def _close_deadline(self, now: int, extra_s: float = 0.0) -> int:
        # Long enough for a lagging source to catch up (the sim holds its sensors back while it
        # plans a run, up to seconds on a loaded machine); a stalled channel ends the wait.
        slowest = max((1.0 / a.rate_hz for a in self.accounts.values() if a.rate_hz > 0), default=0.0)
        grace_s = max(CLOSE_GRACE_S, 4 * self.poll_interval_s, 3 * slowest / self.speed)
        return now + round((extra_s + grace_s) * 1e9)

    # -- closing ----------------------------------------------------------------------------------

    def close_ready(self, now_mono_ns: int | None = None) -> list[ClosedWindow]:
        """Close every window that is ready (after each batch, and after a stop)."""
        if not self.windows:
            return []
        now = self.monotonic() if now_mono_ns is None else now_mono_ns
        closed = []
        for window in [w for w in self.windows if w.ready(now)]:
            self.windows.remove(window)
            closed.append(self._close(window, now))
        return closed

    def _close(self, window: Window, now: int) -> ClosedWindow:
        energy, window_s, spans = window.result(self.energies(), self.last_sample_times(), now_mono_ns=now,
                                                speed=self.speed)
        run = window.run
        if window.kind == "job":
            return ClosedWindow(kind="job", window_s=window_s, window=window, energy_j=energy)
        if run is None:
            found = self._window_baselines(window, energy, spans, origin="measured")
            return ClosedWindow(kind="baseline", window_s=window_s, baselines=found, kept=self._keep(found))
        record = run.finish(energy_j=energy, window_s=window_s, dram_channels=self.dram_channels,
                            t_wall_ns=self.wall(), spans_s=spans, aborted=window.abort)
        # The window on each channel's sample axis: samples with first < t <= last are inside.
        record.samples_ns = {c: list(span) for c, span in window.sample_spans_ns.items()}
        self.runs_finished += 1
        found, kept = {}, {}
        if record.moves_no_traffic and not window.abort:
            found = self._window_baselines(window, energy, spans, origin="idle-run")
            kept = self._keep(found)
        return ClosedWindow(kind="run", window_s=window_s, run=record, baselines=found, kept=kept)

    # -- baselines --------------------------------------------------------------------------------

    def _window_baselines(self, window: Window, energy: Mapping[str, float], spans: Mapping[str, float],
                          origin: bl.Origin) -> dict[str, bl.Baseline]:
        found = {}
        for name, account in self.accounts.items():
            baseline = bl.baseline_from_samples(window.channel_samples(name), t_ns=account.last_t_ns or 0,
                                                origin=origin, energy_j=energy.get(name),
                                                window_s=spans.get(name))
            if baseline is not None:
                found[name] = baseline
        return found

    def _keep(self, found: Mapping[str, bl.Baseline]) -> dict[str, bl.Baseline]:
        """Merge new baselines into the kept ones; return those that replaced the kept one."""
        kept = {}
        for channel, baseline in found.items():
            current = self.baselines.get(channel)
            merged = bl.merge(current, baseline)
            if merged is not None and merged is not current:
                self.baselines[channel] = merged
                kept[channel] = merged
        return kept

    def quiet_baselines(self, *, window_s: float, max_spread_w: float) -> dict[str, bl.Baseline]:
        """Baselines from quiet periods of the recent samples (only while no window is open);
        returns those kept."""
        if self.exclusive_windows():
            return {}
        found = {}
        for name in self.dram_channels:
            account = self.accounts[name]
            ring = account.history
            if ring is None or len(ring) == 0:
                continue
            values = ring.values()
            quiet = bl.quiet_window(values, rate_hz=account.rate_hz, window_s=window_s, max_spread_w=max_spread_w)
            if quiet is None:
                continue
            baseline = bl.baseline_from_samples(values[quiet[0]:quiet[1]], t_ns=account.last_t_ns or 0,
                                                origin="quiet")
            if baseline is not None:
                found[name] = baseline
        return self._keep(found)
