"""The node daemon process: sockets, the poll loop, heartbeat, persistence and the model worker.

One thread runs everything that touches sockets, the source and SQLite: a ZeroMQ poll loop that
wakes for control requests, new subscriptions and three fixed-rate deadlines (poll the source,
heartbeat, re-publish calibration/baselines and look for quiet periods). The kernel model and the
refit run in one worker thread (:class:`~hdeem_watch.daemon.modelling.RunModeller`); their results
are picked up by the loop, stored and published. The control operations are in
:mod:`hdeem_watch.daemon.operations`.

Example:
    >>> from hdeem_watch.config import DaemonSettings
    >>> daemon = Daemon(DaemonSettings(state_dir="/tmp/x"))       # doctest: +SKIP
    >>> daemon.start(); daemon.run()                              # doctest: +SKIP
"""

from __future__ import annotations

import collections
import fcntl
import logging
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import psutil
import zmq

from hdeem_watch import __version__
from hdeem_watch.config import DaemonSettings
from hdeem_watch.daemon import baselines as bl
from hdeem_watch.daemon.channels import ChannelAccount
from hdeem_watch.daemon.client import default_endpoints, ipc_path
from hdeem_watch.daemon.control import ControlServer, Pending
from hdeem_watch.daemon.jobs import ModelJobs, load_state
from hdeem_watch.daemon.metrics import DaemonMetrics
from hdeem_watch.daemon.modelling import RunModeller
from hdeem_watch.daemon.operations import Operations
from hdeem_watch.daemon.poller import IntervalTimer
from hdeem_watch.daemon.publisher import Publisher
from hdeem_watch.daemon.reporting import Reporter
from hdeem_watch.daemon.store import Store, StoreError
from hdeem_watch.daemon.windows import Window
from hdeem_watch.errors import InputError

log = logging.getLogger("hdeem_watch.daemon")

#: Longest stretch of source time between two idle polls (s).
IDLE_MAX_SOURCE_S = 10.0

Clock = Callable[[], int]


class Daemon:
    """One node daemon.

    Args:
        settings: the configuration.
        source: a ready source object (default: ``make_source(settings.source, ...)``).
        clock: monotonic clock in ns (shared with the source's ``on_run`` events).
        context: ZeroMQ context.
    """

    def __init__(self, settings: DaemonSettings, *, source: Any = None, clock: Clock = time.monotonic_ns,
                 context: zmq.Context[Any] | None = None) -> None:
        self.settings = settings
        self.node = settings.node
        self.clock = clock
        self.context = context or zmq.Context.instance()
        self.source = source
        default_pub, default_control = default_endpoints(settings.runtime_dir)
        self.pub_endpoint = settings.pub or default_pub
        self.control_endpoint = settings.control or default_control
        self.accounts: dict[str, ChannelAccount] = {}
        self.dram_channels: tuple[str, ...] = ()
        self.baselines: dict[str, bl.Baseline] = {}
        self.windows: list[Window] = []
        self.calib_body: dict[str, Any] = {}
        self.jobs = ModelJobs()
        self.publisher: Publisher | None = None
        self.control: ControlServer | None = None
        self.store: Store | None = None
        self.modeller: RunModeller | None = None
        self.metrics: DaemonMetrics | None = None
        self.metrics_port: int | None = None
        self.recorder: Any = None
        self.curve: Any = None
        self.operations = Operations(self)
        self.reporter = Reporter(self)
        self._stop = False
        self._lock_file: Any = None
        self._process = psutil.Process()
        self._t_open_mono = 0
        self._last_health = "ok"
        self._metric_last: dict[str, tuple[float, int, int]] = {}
        self._cpu_percent = math.nan
        self.poll_interval_ns = round(settings.poll_interval_s * 1e9)
        self.polls = 0
        self.poll_errors = 0
        self._offsets: collections.deque[int] = collections.deque(maxlen=400)
        self._speed_of: object = None
        self._speed = 1.0

    # -- lifecycle -------------------------------------------------------------------------------------

    def start(self) -> None:
        """Lock the state directory, load state, open the source, bind the sockets.

        Raises:
            InputError: another daemon uses the state directory, an endpoint cannot be bound, the
                source is unavailable (with its reason) or the state database is unusable.
        """
        try:
            self._start()
        except BaseException:
            self.close()
            raise

    def _start(self) -> None:
        state_dir = Path(self.settings.state_dir)
        try:
            state_dir.mkdir(parents=True, exist_ok=True, mode=0o750)
            self._lock_file = open(state_dir / "daemon.lock", "w")  # noqa: SIM115 - held for the process life
            fcntl.flock(self._lock_file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise InputError(f"state dir {state_dir}: another hdeem-watch daemon is using it") from None
        except OSError as error:
            raise InputError(f"state dir {state_dir}: {error.strerror}") from None
        try:
            self.store = Store(state_dir / "state.db")
        except StoreError as error:
            raise InputError(str(error)) from None
        self.store.close_interrupted_runs(time.time_ns())
        if self.source is None:
            from hdeem_watch.sources.base import SourceUnavailable, make_source

            try:
                self.source = make_source(self.settings.source, **self.settings.source_options())
                self.source.open()
            except SourceUnavailable as error:
                kind = self.settings.source
                reason = error.reason[len(kind) + 1:].strip() if error.reason.startswith(f"{kind}:") else error.reason
                raise InputError(f"source {kind}: {reason}") from None
        else:
            self.source.open()
        infos = self.source.channels()
        self.accounts = {
            i.name: ChannelAccount(i.name, i.rate_hz, i.kind, history_s=self.settings.quiet_history_s) for i in infos
        }
        self.dram_channels = tuple(i.name for i in infos if i.kind == "dram")
        if self.settings.record_file:
            from hdeem_watch.sources.replay import RecordingWriter

            try:
                self.recorder = RecordingWriter(self.settings.record_file, node=self.node,
                                                rate_hz={i.name: i.rate_hz for i in infos})
            except OSError as error:
                raise InputError(f"record file {self.settings.record_file}: {error.strerror}") from None
        secure = None
        if self.settings.curve_secret_key_file:
            from hdeem_watch.daemon.security import CurveServer

            self.curve = CurveServer(self.context, self.settings.curve_secret_key_file, self.settings.curve_clients_dir)
            secure = self.curve.apply
        try:
            self.publisher = Publisher(self.context, self.pub_endpoint, node=self.node, sndhwm=self.settings.sndhwm,
                                       secure=secure)
            self.control = ControlServer(self.context, self.control_endpoint, self.operations.handlers(),
                                         secure=secure)
        except (zmq.ZMQError, OSError) as error:
            self._close_sockets()
            raise InputError(f"cannot bind {self.pub_endpoint} / {self.control_endpoint}: {error}") from None
        self.pub_endpoint, self.control_endpoint = self.publisher.endpoint, self.control.endpoint
        load_state(self)
        if self.settings.prometheus_port is not None:
            self.metrics = DaemonMetrics(self.node)
            try:
                self.metrics_port = self.metrics.serve(self.settings.prometheus_port, self.settings.prometheus_addr)
            except OSError as error:
                self._close_sockets()
                raise InputError(f"prometheus port {self.settings.prometheus_port}: {error.strerror}") from None
        self._t_open_mono = self.clock()
        self._process.cpu_percent(None)
        log.info("hdeem-watch daemon %s: node %s, source %s, pub %s, control %s", __version__, self.node,
                 self.settings.source, self.pub_endpoint, self.control_endpoint)

    def request_stop(self) -> None:
        """Ask the loop to end (safe from a signal handler)."""
        self._stop = True

    def close(self) -> None:
        """Finish the model jobs, close the sockets, the source and the database."""
        self.jobs.shutdown()
        self._close_sockets()
        if self.metrics is not None:
            self.metrics.close()
        if self.recorder is not None:
            self.recorder.close()
            self.recorder = None
        if self.curve is not None:
            self.curve.close()
            self.curve = None
        if self.source is not None:
            try:
                self.source.close()
            except Exception as error:
                log.warning("source close failed: %s", error)
        if self.store is not None:
            self.store.close()
            self.store = None
        if self._lock_file is not None:
            self._lock_file.close()
            self._lock_file = None
        if self.polls:
            log.info("hdeem-watch daemon stopped (%d polls)", self.polls)

    def _close_sockets(self) -> None:
        for part in (self.publisher, self.control):
            if part is not None:
                part.close()
                path = ipc_path(part.endpoint)
                if path is not None:
                    path.unlink(missing_ok=True)
        self.publisher = self.control = None

    # -- the loop --------------------------------------------------------------------------------------

    def run(self) -> None:
        """Serve until :meth:`request_stop` (or SIGTERM/SIGINT via the command line).

        One iteration per wake-up, kept lean (it runs 25 times a second): one clock read for the
        timeout, one for the deadlines, ZeroMQ's compiled poll on a prebuilt list; the poll period is
        re-derived only when subscriptions or windows changed.
        """
        assert self.publisher is not None and self.control is not None
        clock = self.clock
        self.poll_interval_ns = self._poll_interval_ns()
        poll_timer = IntervalTimer(self.poll_interval_ns, clock=clock)
        heartbeat = IntervalTimer(round(self.settings.heartbeat_s * 1e9), clock=clock)
        republish = IntervalTimer(round(self.settings.republish_s * 1e9), clock=clock, start_ns=clock())
        control_socket, pub_socket = self.control.socket, self.publisher.socket
        zmq_poll = zmq.backend.zmq_poll  # what zmq.Poller.poll calls, without its Python layer
        items = [(control_socket, zmq.POLLIN), (pub_socket, zmq.POLLIN)]
        self.poll_once()
        open_windows = len(self.windows)
        # The heartbeat and the re-publication are served at the first poll after their deadline
        # (at most one poll period late) instead of waking the loop once more for them.
        slowest_ns = min(heartbeat.interval_ns, republish.interval_ns) // 4
        coalesce = poll_timer.interval_ns <= slowest_ns
        while not self._stop:
            wake = poll_timer.next_ns if coalesce else min(poll_timer.next_ns, heartbeat.next_ns, republish.next_ns)
            timeout_ms = min(100, max(0, -(-(wake - clock()) // 1_000_000)))
            changed = False
            for sock, _event in zmq_poll(items, timeout_ms):
                if sock is control_socket:
                    self.control.handle()
                elif sock is pub_socket:
                    self.publisher.handle_subscriptions()
                    changed = True
            now = clock()
            if now >= poll_timer.next_ns:
                poll_timer.advance(now)
                self.poll_once()
            if now >= heartbeat.next_ns:
                heartbeat.advance(now)
                self.reporter.publish_status()
            if now >= republish.next_ns:
                republish.advance(now)
                self.reporter.look_for_quiet_periods()
                self.reporter.publish_calib()
                self.reporter.publish_baselines()
            if self.jobs.pending:
                self.jobs.collect()
            if changed or len(self.windows) != open_windows:
                open_windows = len(self.windows)
                interval_ns = self._poll_interval_ns()
                if interval_ns != poll_timer.interval_ns:
                    poll_timer.set_interval(interval_ns)
                    coalesce = interval_ns <= slowest_ns
                    self.poll_interval_ns = interval_ns

    def _poll_interval_ns(self) -> int:
        """The fast poll period while someone receives samples or a window is open, else the idle one."""
        fast, idle = self.settings.poll_interval_s, self.settings.idle_poll_interval_s
        watched = self.publisher is not None and self.publisher.watched("samples")
        if watched or idle <= 0 or self.windows:
            return round(fast * 1e9)
        # At most 10 s of source time per poll: a sped-up sim's sensor buffer (60 sim-s) must not overflow.
        return round(max(fast, min(idle, IDLE_MAX_SOURCE_S / self.speed)) * 1e9)

    def submit(self, job: Callable[[], Any], done: Callable[[Any], None],
               failed: Callable[[BaseException], None] | None = None) -> None:
        """Run ``job`` on the model worker; in the loop, call ``done(result)`` or ``failed(error)``."""
        self.jobs.submit(job, done, failed)

    # -- polling ---------------------------------------------------------------------------------------

    def poll_once(self) -> Any:
        """Poll the source, account and publish every channel, advance the windows; return the batch."""
        assert self.publisher is not None
        self.polls += 1
        try:
            batch = self.source.poll()
        except Exception as error:  # a sensor failure must not end the daemon
            self.poll_errors += 1
            message = f"error: {type(error).__name__}: {error}"
            if message != self._last_health:
                log.warning("source poll failed: %s", message)
            self._last_health = message
            for failed in self.accounts.values():
                failed.status = message
            return None
        # The hot path (25 times a second): locals instead of attribute look-ups, nothing per poll
        # that only changes with the windows.
        windows = self.windows
        keep_history = not (windows and any(w.kind == "run" for w in windows))
        header_t_ns = time.time_ns()
        accounts, energies, statuses, gaps = self.accounts, batch.energy_j, batch.status, batch.gaps
        encode = self.publisher.samples_message
        outgoing: list[list[bytes]] = []
        nan = math.nan
        for name, (t_ns, power_w) in batch.samples.items():
            account = accounts.get(name)
            if account is None:
                continue
            energy = energies.get(name, nan)
            status = statuses.get(name, "ok")
            # An empty batch is published only when it says something new (a rate-limited sensor,
            # e.g. HDEEM read every 0.1 s, gives empty batches at most polls).
            news = account.take(t_ns, power_w, energy, status, int(gaps.get(name, 0)) if gaps else 0, keep_history)
            for window in windows:
                window.observe(name, t_ns, power_w, energy_j=energy)
            if news:
                outgoing.append(encode(name, account.rate_hz, t_ns, power_w, energy, status, header_t_ns))
        # All channels at once: one wake-up of the I/O thread per poll, not one per message.
        self.publisher.send_all(outgoing)
        speed = self.speed
        self._offsets.append(batch.t_wall_ns - (batch.t_mono_ns if speed == 1.0 else round(batch.t_mono_ns * speed)))
        if self.recorder is not None:
            self.recorder.write_batch(batch)
        if windows:
            self.operations.advance_windows(self.clock())
        return batch

    def sample_time_of(self, t_mono_ns: int) -> int:
        """A monotonic instant on the source's sample-time axis (wall ns; the sim's own time).

        From the recent polls' ``t_wall_ns − t_mono_ns × speed``: a source that lags (holds its
        samples back for a while) only lowers that offset, so the largest recent one is the true
        mapping.
        """
        if not self._offsets:
            return time.time_ns()
        return round(int(t_mono_ns) * self.speed) + max(self._offsets)

    def rates(self) -> dict[str, float]:
        """The nominal rate of every channel."""
        return {name: a.rate_hz for name, a in self.accounts.items()}

    def last_sample_times(self) -> dict[str, int | None]:
        """The last sample time of every channel."""
        return {name: a.last_t_ns for name, a in self.accounts.items()}

    def energies(self) -> dict[str, float]:
        """The cumulative energy of every channel."""
        return {name: a.energy_j for name, a in self.accounts.items()}

    @property
    def speed(self) -> float:
        """Source seconds per monotonic second (sim/replay speed; 1 for real sensors)."""
        value = getattr(self.source, "speed", 1.0)
        if value is self._speed_of:  # the same object as last time (read at every poll)
            return self._speed
        self._speed_of = value
        self._speed = float(value) if isinstance(value, int | float) and value > 0 else 1.0
        return self._speed

    def complete(self, pending: Pending, result: Any = None, error: tuple[str, str] | None = None) -> None:
        """Send a deferred control reply."""
        if self.control is not None:
            self.control.complete(pending, result, error=error)

