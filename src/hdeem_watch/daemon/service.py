"""The node daemon process: the shell around the run book — sockets, the poll loop, the workers.

The decisions (accounting, run and idle windows, baselines) are the pure
:class:`~hdeem_watch.daemon.book.state.NodeState`'s; this module wires it to the world. One thread
runs the ZeroMQ poll loop: it wakes for control requests, subscriptions, finished worker jobs (and
signals) through their sockets and its wake-up pipe, and for one timer, the next poll. The poll
period is :class:`~hdeem_watch.daemon.shell.poll_policy.PollPolicy`'s: full rate while a subscriber takes
samples or a run or baseline window is open, the source's quiet limit while nobody watches. The
heartbeat and the re-publication (calibration, baselines, quiet periods) are served at the first
poll after their deadline; they wake the loop on their own only while someone listens and the poll
period is longer than they are. Two worker threads do the slow work, sleeping on their queues: the
model worker (kernel model, refit; :mod:`hdeem_watch.daemon.shell.workers`) and the store worker (every
database read and write after start; :mod:`hdeem_watch.daemon.store.worker`). Their callbacks run in
the loop. The control operations are in :mod:`hdeem_watch.daemon.ops.node`, the topics in
:mod:`hdeem_watch.daemon.ops.reporting`.

Example:
    >>> from hdeem_watch.config import DaemonSettings
    >>> daemon = Daemon(DaemonSettings(state_dir="/tmp/x"))       # doctest: +SKIP
    >>> daemon.start(); daemon.run()                              # doctest: +SKIP
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import re
import signal
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import IO, Any

import zmq

from hdeem_watch import __version__
from hdeem_watch.calibrate.group_fits import source_groups
from hdeem_watch.calibrate.run_model import MAX_HISTORY
from hdeem_watch.config import DaemonSettings
from hdeem_watch.daemon.book import baselines as bl
from hdeem_watch.daemon.book.runs import RunLimits
from hdeem_watch.daemon.book.state import NodeState
from hdeem_watch.daemon.compose import NodeCore, NodePorts, build_node
from hdeem_watch.daemon.counters.feed import CounterFeed
from hdeem_watch.daemon.ops.jobs import JobOperations, unfinished_jobs, unmodelled_jobs
from hdeem_watch.daemon.ops.node import Operations, unfinished_runs
from hdeem_watch.daemon.ops.reporting import Identity, Reporter
from hdeem_watch.daemon.shell.authorization import Authorizer
from hdeem_watch.daemon.shell.control import ControlServer, Pending
from hdeem_watch.daemon.shell.endpoints import advertised_endpoints
from hdeem_watch.daemon.shell.metrics import DaemonMetrics, NodeCollector
from hdeem_watch.daemon.shell.poll_policy import PollDemand, PollPolicy
from hdeem_watch.daemon.shell.poller import IntervalTimer
from hdeem_watch.daemon.shell.publisher import Publisher
from hdeem_watch.daemon.shell.workers import Calibration, ModelSettings, Worker, restore_calibration
from hdeem_watch.daemon.store.checks import ROW_CHECKS
from hdeem_watch.daemon.store.database import Store, StoreError
from hdeem_watch.daemon.store.worker import StoreWorker
from hdeem_watch.errors import InputError
from hdeem_watch.sources.base import (
    ChannelInfo,
    HasLayout,
    QuietPolling,
    Source,
    SourceBatch,
    SourceUnavailable,
    source_speed,
)
from hdeem_watch.sources.registry import make_source, simulated_memspec
from hdeem_watch.wire.client import default_endpoints
from hdeem_watch.wire.json_codec import quoted

log = logging.getLogger("hdeem_watch.daemon")

Clock = Callable[[], int]

#: Longest slice of control work (requests, worker callbacks) between two looks at the poll
#: deadline: a crowd of clients delays replies, not samples.
WORK_SLICE_NS = 4_000_000


class Daemon:
    """One node daemon.

    Args:
        settings: the configuration.
        source: a ready source object (default: ``make_source(settings.source, ...)``).
        clock: monotonic clock in ns (shared with the source's run events).
        wall_clock: wall clock in ns (labels: record and header times).
        context: ZeroMQ context.
        job_owner_uids: the uids owning a job running on the node (they may change state); default
            the daemon's job book's ``running_job_uids``.
    """

    def __init__(self, settings: DaemonSettings, *, source: Source | None = None, clock: Clock = time.monotonic_ns,
                 wall_clock: Clock = time.time_ns, context: zmq.Context[Any] | None = None,
                 job_owner_uids: Callable[[], frozenset[int]] | None = None) -> None:
        self.settings = settings
        self.node = settings.node
        self.clock = clock
        self.wall_clock = wall_clock
        self.context = context or zmq.Context.instance()
        self.source = source
        default_pub, default_control = default_endpoints(settings.runtime_dir)
        self.pub_endpoint = settings.pub or default_pub
        self.control_endpoint = settings.control or default_control
        self.authorizer = Authorizer(job_owner_uids=job_owner_uids or frozenset)
        self._job_owner_uids_given = job_owner_uids is not None
        self.book: NodeState | None = None
        self.calibration = Calibration()
        self.publisher: Publisher | None = None
        self.control: ControlServer | None = None
        self.store: Store | None = None
        self.store_worker: StoreWorker | None = None
        self.model_jobs: Worker | None = None
        self.operations: Operations | None = None
        self.job_ops: JobOperations | None = None
        self.reporter: Reporter | None = None
        #: The node's core (run book, reporter, ops, window router), wired by :func:`build_node`.
        self.core: NodeCore | None = None
        self.metrics: DaemonMetrics | None = None
        self.metrics_port: int | None = None
        self.recorder: Any = None
        self.node_setup: Any = None
        self.curve: Any = None
        self.poll_interval_ns = round(settings.poll_interval_s * 1e9)
        #: How often to poll (set at start, from the source's quiet limit).
        self.poll_policy = PollPolicy(settings.poll_interval_s, settings.idle_poll_interval_s)
        #: Whether some subscriber takes samples (the samples of a poll are encoded only then).
        self.stream_samples = False
        self._stop = False
        self._lock_file: IO[str] | None = None
        self._wake_r, self._wake_w = -1, -1
        self._source_open = False
        #: The memory-controller counters (``counters`` setting); None = off.
        self.counters: CounterFeed | None = None

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

    def _lock(self, state_dir: Path) -> None:
        try:
            state_dir.mkdir(parents=True, exist_ok=True, mode=0o750)
            fd = os.open(state_dir / "daemon.lock", os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
            self._lock_file = os.fdopen(fd, "w")
            os.fchmod(fd, 0o600)  # the lock is the daemon's alone (an older daemon made it 0660)
            fcntl.flock(self._lock_file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise InputError(f"state dir {state_dir}: another hdeem-watch daemon is using it") from None
        except OSError as error:
            raise InputError(f"state dir {state_dir}: {error.strerror}") from None

    def _open_source(self) -> Source:
        if self.source is None:
            kind = self.settings.source
            try:
                self.source = make_source(kind, **self.settings.source_options())
                self.source.open()
            except SourceUnavailable as error:
                reason = error.reason[len(kind) + 1:].strip() if error.reason.startswith(f"{kind}:") else error.reason
                raise InputError(f"source {kind}: {reason}") from None
        else:
            self.source.open()
        self._source_open = True
        return self.source

    def _describe_node(self, source: Source) -> Any:
        """The node the run model works on (:func:`hdeem_watch.node.setup.node_setup`): the simulated
        node's layout for the sim, this machine detected for hdeem and rapl, the ``[node]`` table
        alone for a replayed recording; the ``[node]`` table over it."""
        from dataclasses import replace

        from hdeem_watch.node.setup import (
            configured_only,
            counted_node,
            detect_live_node,
            node_setup,
            saved_dmidecode,
        )

        overrides = self.settings.node_overrides()
        default = None
        preset = simulated_memspec(source)
        if isinstance(source, HasLayout) and preset is not None:  # the simulated node
            topology = source.layout.topology
            default = (preset, "the simulated node's DIMMs (its hidden truth is built on this preset)")
            description = counted_node(topology.sockets, topology.cores_per_socket, topology.channels_per_socket,
                                       source="sim: the simulated node")
            if overrides is not None:  # its counts went to the sim itself; memspec and name stay
                overrides = replace(overrides, counts={}, dimm={}, sensors={})
        elif source.kind == "replay":
            description = configured_only("a replayed recording: describe its node in the [node] table")
        else:
            description = detect_live_node(dmidecode=saved_dmidecode(overrides))
        return node_setup(description, overrides, memspec_setting=self.settings.memspec, default_memspec=default)

    def _start(self) -> None:
        settings = self.settings
        state_dir = Path(settings.state_dir)
        self._lock(state_dir)
        try:
            store = self.store = Store(state_dir / "state.db", row_checks=ROW_CHECKS)
        except StoreError as error:
            raise InputError(str(error)) from None
        store.close_interrupted_runs(self.wall_clock())
        source = self._open_source()
        setup = self.node_setup = self._describe_node(source)
        infos = source.channels()
        limit = source.quiet_limit if isinstance(source, QuietPolling) else None
        self.poll_policy = PollPolicy(settings.poll_interval_s, settings.idle_poll_interval_s, limit=limit,
                                      speed=source_speed(source), heartbeat_s=settings.heartbeat_s,
                                      checkpoint_s=settings.job_checkpoint_s)
        dram_rates = {info.name: float(info.rate_hz) for info in infos if info.kind == "dram"}
        baselines = self._stored_baselines(store)
        book = self.book = NodeState(
            infos, node=self.node, monotonic=self.clock, wall=self.wall_clock, speed=source_speed(source),
            poll_interval_s=settings.poll_interval_s, history_s=settings.quiet_history_s,
            next_seq=int(store.next_run_id()[1:]), baselines=baselines, limits=RunLimits.of_this_node(),
            paced=limit is not None and limit.paced)
        start_notes = self._open_counters_and_recorder(source, book, infos, memspec=setup.memspec)
        self._wake_r, self._wake_w = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
        self.store_worker = StoreWorker(store, self._wake)
        self.model_jobs = Worker("model", self._wake)
        publisher, control = self._bind_sockets()
        self._serve_metrics(book, self.store_worker)
        core = self.core = self._build_core(book, source, publisher, control)
        self.reporter, self.operations, job_ops = core.reporter, core.operations, core.job_ops
        self.job_ops = job_ops
        if not self._job_owner_uids_given:
            self.authorizer.job_owner_uids = job_ops.jobs.running_job_uids
        control.handlers = core.handlers() | {"node.get": lambda _args: setup.to_json()}
        job_ops.resume(unfinished_jobs(store))
        restore_calibration(
            self.calibration, settings=self._model_settings(source, setup, dram_rates),
            state=store.load_calibrator(), fits=store.fit_history(MAX_HISTORY), submit=self.model_jobs.submit,
            on_built=core.reporter.publish_calib, on_unrestorable=self._quarantine_calibrator)
        core.operations.resume_modelling(unfinished_runs(store))
        job_ops.remodel(unmodelled_jobs(store))
        for line in (*setup.log_lines(), *start_notes):  # once started: a start that fails says one line only
            log.info("%s", line)
        log.info("hdeem-watch daemon %s: node %s, source %s, pub %s, control %s", __version__, self.node,
                 settings.source, self.pub_endpoint, self.control_endpoint)

    def _build_core(self, book: NodeState, source: Source, publisher: Publisher, control: ControlServer) -> NodeCore:
        """The node's core over ``book`` (:func:`~hdeem_watch.daemon.compose.build_node`)."""
        assert self.store_worker is not None and self.model_jobs is not None
        identity = Identity(kind=source.kind,
                            endpoints={"pub": self.pub_endpoint, "control": self.control_endpoint,
                                       "remote": advertised_endpoints(publisher.endpoint, control.endpoints)},
                            curve_public_key=None if self.curve is None else self.curve.public.decode(),
                            prometheus_port=self.metrics_port)
        ports = NodePorts(store=self.store_worker, submit=self.model_jobs.submit, publisher=publisher,
                          reply=self.complete, poll=self._edge_poll)
        counters = self.counters
        return build_node(book, source, self.clock, ports, identity=identity, calibration=self.calibration,
                          poll_interval_ns=lambda: self.poll_interval_ns,
                          counter_windows=counters.windows if counters is not None else None,
                          observers=[counters.window_closed] if counters is not None else [],
                          checkpoint_s=self.settings.job_checkpoint_s)

    def _model_settings(self, source: Source, setup: Any, dram_rates: dict[str, float]) -> ModelSettings:
        """What the model worker models runs with: memspec, topology, currents, sensor groups."""
        settings, topo = self.settings, setup.topology
        groups = source_groups(source, dram_rates, sockets=topo.sockets if topo else 2,
                               dimms_per_socket=topo.dimms // topo.sockets if topo else max(1, settings.dimms // 2))
        return ModelSettings(setup.memspec, dimms=settings.dimms, topology=topo, currents=self._currents(),
                             half_life_s=settings.half_life_s or None, physical_rules=settings.physical_rules,
                             max_requests=settings.model_max_requests, groups=groups, dram_rates_hz=dram_rates)

    def _open_counters_and_recorder(self, source: Source, book: NodeState, infos: Sequence[ChannelInfo], *,
                                    memspec: str) -> list[str]:
        """Open the memory-controller counters and the ``--record`` writer; the lines to log once started."""
        settings, notes = self.settings, list[str]()
        self.counters = CounterFeed.open(settings.counters, source, book, memspec=memspec, clock=self.clock,
                                         heartbeat_s=settings.heartbeat_s, record_file=settings.record_file,
                                         replay_file=settings.replay_file, source_kind=settings.source, notes=notes)
        if settings.record_file:
            from hdeem_watch.sources.replay import RecordingWriter

            try:
                self.recorder = RecordingWriter(settings.record_file, node=self.node,
                                                rate_hz={i.name: i.rate_hz for i in infos})
            except OSError as error:
                raise InputError(f"record file {settings.record_file}: {error.strerror}") from None
        return notes

    @staticmethod
    def _stored_baselines(store: Store) -> dict[str, bl.Baseline]:
        """The idle baselines kept in ``store`` by channel (a malformed one is skipped with a warning)."""
        baselines = {}
        for channel, data in store.load_baselines().items():
            try:
                baselines[channel] = bl.Baseline.from_dict(data)
            except (ValueError, TypeError):
                log.warning("ignoring a malformed stored baseline of %s", channel)
        return baselines

    def _bind_sockets(self) -> tuple[Publisher, ControlServer]:
        """Bind the publisher and the control server (with CURVE if configured); a bind failure is an input error."""
        settings = self.settings
        secure = None
        if settings.curve_secret_key_file:
            from hdeem_watch.daemon.shell.security import CurveServer

            self.curve = CurveServer(self.context, settings.curve_secret_key_file, settings.curve_clients_dir)
            secure = self.curve.apply
        try:
            self.publisher = Publisher(self.context, self.pub_endpoint, node=self.node, sndhwm=settings.sndhwm,
                                       secure=None if self.pub_endpoint.startswith("ipc://") else secure)
            self.control = ControlServer(
                self.context, self.control_endpoint, {}, secure=secure, authorizer=self.authorizer,
                extra_endpoints=(settings.remote_control,) if settings.remote_control else ())
        except (zmq.ZMQError, OSError) as error:
            self._close_sockets()
            raise InputError(bind_failure(error, {"--pub": self.pub_endpoint, "--control": self.control_endpoint,
                                                  "--remote-control": settings.remote_control})) from None
        self.pub_endpoint, self.control_endpoint = self.publisher.endpoint, self.control.endpoint
        return self.publisher, self.control

    def _serve_metrics(self, book: NodeState, store_worker: StoreWorker) -> None:
        """Serve the Prometheus metrics of ``book`` if a port is configured; a port in use is an input error."""
        settings = self.settings
        if settings.prometheus_port is not None:
            self.metrics = DaemonMetrics(NodeCollector(
                self.node, accounts=lambda: book.accounts, baselines=lambda: book.baselines,
                fit=lambda: self.calibration.body.get("fit"), runs_finished=lambda: book.runs_finished,
                store_health=store_worker.health))
            try:
                self.metrics_port = self.metrics.serve(settings.prometheus_port, settings.prometheus_addr)
            except OSError as error:
                self._close_sockets()
                raise InputError(f"prometheus port {settings.prometheus_port}: {error.strerror}") from None

    def _quarantine_calibrator(self, why: str, restored: str | None) -> None:
        """The stored calibrator state could not be restored: move it to ``quarantine`` and store
        what was restored of it (the node calibrator without its groups, or a fresh one)."""
        assert self.store_worker is not None
        t_ns = self.wall_clock()
        log.warning("state database: calibrator: %s (moved to table quarantine)", quoted(why))
        self.store_worker.write("calibrator quarantine", lambda s: s.quarantine_calibrator(t_ns, why))
        if restored is not None:
            self.store_worker.write("calibrator", lambda s: s.save_calibrator_state(t_ns, restored))

    def request_stop(self) -> None:
        """Ask the loop to end (safe from a signal handler and from another thread)."""
        self._stop = True
        self._wake()

    def close(self) -> None:
        """Finish the model jobs (queued ones are modelled again at the next start), write what is
        queued for the database, close the sockets, the source and the database."""
        if self.job_ops is not None and self.store_worker is not None:
            self.job_ops.checkpoint(force=True)  # the open jobs' energy up to the exit
        if self.model_jobs is not None:
            self.model_jobs.shutdown(cancel_queued=True)
        if self.store_worker is not None:
            self.store_worker.shutdown()
        self._close_sockets()
        if self.metrics is not None:
            self.metrics.close()
        if self.recorder is not None:
            self.recorder.close()
            self.recorder = None
        if self.curve is not None:
            self.curve.close()
            self.curve = None
        if self.counters is not None:
            self.counters.close()
            self.counters = None
        if self.source is not None and self._source_open:
            self._source_open = False
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
        for fd in (self._wake_r, self._wake_w):
            if fd >= 0:
                os.close(fd)
        self._wake_r = self._wake_w = -1
        if self.book is not None and self.book.polls:
            log.info("hdeem-watch daemon stopped (%d polls)", self.book.polls)

    def _close_sockets(self) -> None:
        # Each part unlinks the ipc socket file it created (and only that) in its own close().
        for part in (self.publisher, self.control):
            if part is not None:
                part.close()
        self.publisher = self.control = None

    def _wake(self) -> None:
        """Wake the poll loop (from a worker thread: a job finished)."""
        with contextlib.suppress(OSError):  # full (the loop wakes anyway) or closed (shutting down)
            os.write(self._wake_w, b"\0")

    # -- the loop --------------------------------------------------------------------------------------

    def run(self) -> None:
        """Serve until :meth:`request_stop` (or SIGTERM/SIGINT via the command line).

        The loop sleeps until the next poll, a control request, a subscription or a finished worker
        job: nothing else wakes it (a signal writes to the wake-up pipe).
        """
        assert self.publisher is not None and self.book is not None
        with self._signals_wake_loop():
            self._serve()

    @contextlib.contextmanager
    def _signals_wake_loop(self) -> Iterator[None]:
        """Signals write to the wake-up pipe while the loop runs (only the main thread may set it):
        a SIGTERM that another thread receives still ends a long quiet wait at once."""
        if threading.current_thread() is not threading.main_thread():
            yield
            return
        previous = signal.set_wakeup_fd(self._wake_w, warn_on_full_buffer=False)
        try:
            yield
        finally:
            signal.set_wakeup_fd(previous)

    def _serve(self) -> None:
        assert self.publisher is not None and self.control is not None and self.book is not None
        assert self.reporter is not None and self.store_worker is not None and self.model_jobs is not None
        clock, settings, book, publisher = self.clock, self.settings, self.book, self.publisher
        demand = self._demand()
        self.poll_interval_ns = self.poll_policy.interval_ns(demand)
        poll_timer = IntervalTimer(self.poll_interval_ns, clock=clock)
        heartbeat = IntervalTimer(round(settings.heartbeat_s * 1e9), clock=clock)
        republish = IntervalTimer(self._republish_ns(demand), clock=clock, start_ns=clock())
        control_sockets, pub_socket, wake_fd = self.control.sockets, publisher.socket, self._wake_r
        poller = zmq.Poller()
        for sock in control_sockets:
            poller.register(sock, zmq.POLLIN)
        poller.register(pub_socket, zmq.POLLIN)
        poller.register(wake_fd, zmq.POLLIN)
        self.poll_once()
        windows = _window_shape(book)
        # The heartbeat and the re-publication are served at the first poll after their deadline
        # (at most one poll period late) instead of waking the loop once more for them; while
        # nobody listens, always.
        slowest_ns = min(heartbeat.interval_ns, round(settings.republish_s * 1e9)) // 4
        backlog = False
        while not self._stop:
            wake = poll_timer.next_ns
            if demand.listening and poll_timer.interval_ns > slowest_ns:
                wake = min(wake, heartbeat.next_ns, republish.next_ns)
            timeout_ms = 0 if backlog else max(0, -(-(wake - clock()) // 1_000_000))
            ready = dict(poller.poll(timeout_ms))
            now = clock()
            if now >= poll_timer.next_ns:  # the stream first: control work waits, samples do not
                poll_timer.advance(now)
                self.poll_once()
            changed = pub_socket in ready
            if changed:
                publisher.handle_subscriptions()
            if wake_fd in ready:
                with contextlib.suppress(BlockingIOError):
                    os.read(wake_fd, 4096)
            self._periodic(now, heartbeat, republish)
            backlog = self._work_slice(clock() + WORK_SLICE_NS,
                                       control_waiting=any(sock in ready for sock in control_sockets))
            if changed or _window_shape(book) != windows:  # opened, closed, or asked to close
                windows = _window_shape(book)
                demand = self._retune(demand, poll_timer, republish)

    def _periodic(self, now: int, heartbeat: IntervalTimer, republish: IntervalTimer) -> None:
        """The heartbeat's and the re-publication's work when due (they never wake the loop alone)."""
        assert self.reporter is not None and self.publisher is not None and self.store_worker is not None
        assert self.book is not None
        reporter, settings = self.reporter, self.settings
        if now >= heartbeat.next_ns:
            heartbeat.advance(now)
            reporter.publish_status()
            if self.counters is not None:
                if not self.book.windows:  # with a window open, poll_once reads them when due
                    self.counters.read(force=True)
                self.publisher.publish("counters", self.counters.rates_body())
            if self.job_ops is not None:
                self.job_ops.checkpoint()
            if self.recorder is not None:
                self.recorder.flush()
            if self.counters is not None:
                self.counters.flush()
        if now >= republish.next_ns:
            republish.advance(now)
            reporter.look_for_quiet_periods(window_s=settings.quiet_window_s, max_spread_w=settings.quiet_max_spread_w,
                                            history_s=settings.quiet_history_s)
            reporter.publish_calib()
            reporter.publish_baselines()

    def _retune(self, demand: PollDemand, poll_timer: IntervalTimer, republish: IntervalTimer) -> PollDemand:
        """Follow a change of subscriptions or windows: the new poll period (and a poll at once
        when the stream turns live: a new subscriber gets the buffered samples now) and the new
        re-publication period."""
        now_demand = self._demand()
        if now_demand == demand:
            return demand
        if (republish_ns := self._republish_ns(now_demand)) != republish.interval_ns:
            republish.set_interval(republish_ns)
        interval_ns = self.poll_policy.interval_ns(now_demand)
        if interval_ns != poll_timer.interval_ns:
            faster = interval_ns < poll_timer.interval_ns
            poll_timer.set_interval(interval_ns)
            if faster and now_demand.live and not demand.live:
                poll_timer.next_ns = self.clock()
            self.poll_interval_ns = interval_ns
        return now_demand

    def _work_slice(self, end_ns: int, *, control_waiting: bool) -> bool:
        """Answer control requests and run worker callbacks one at a time until ``end_ns``; return
        whether work is left (the loop then comes back at once, after a poll if one is due)."""
        assert self.control is not None and self.model_jobs is not None and self.store_worker is not None
        control, models, store, clock = self.control, self.model_jobs, self.store_worker, self.clock
        while True:
            if control_waiting:
                control.handle(max_messages=1)
                # Only an answered request can hide another one (one that arrives later wakes the
                # next poll): asking every socket at every poll was a tenth of the watched loop.
                control_waiting = control.waiting()
            if models.pending and models.ready:
                models.collect(1)
            if store.pending and store.ready:
                store.collect(1)
            left = control_waiting or (models.pending and models.ready) or (store.pending and store.ready)
            if not left or clock() >= end_ns:
                return bool(left)

    def _republish_ns(self, demand: PollDemand) -> int:
        """The re-publication period: ``republish_s`` while someone listens; otherwise (the cached
        topics reach a late joiner anyway) as often as the quiet-period search sees new samples,
        once per ``quiet_history_s`` of source time."""
        assert self.book is not None
        settings = self.settings
        seconds = settings.republish_s
        if not demand.listening:
            seconds = max(seconds, settings.quiet_history_s / self.book.speed)
        return round(seconds * 1e9)

    def _demand(self) -> PollDemand:
        """What asks for polls now: subscribers, open windows, open jobs."""
        assert self.book is not None and self.publisher is not None
        self.stream_samples = self.publisher.watched("samples")
        windows = self.book.windows
        # a job window that is closing waits for the sample at its stop: full rate until it has it
        # (else job.stop would answer only at the next checkpoint poll, seconds later)
        return PollDemand(watched=self.stream_samples, listening=bool(self.publisher.prefixes),
                          window_open=any(w.kind != "job" or w.closing for w in windows),
                          jobs_open=any(w.kind == "job" for w in windows))

    # -- polling ---------------------------------------------------------------------------------------

    def poll_once(self, *, force_counters: bool = False) -> SourceBatch | None:
        """Poll the source; account, publish and window the batch; return it (None if the poll failed).
        While a window is open the counters are read when due, when a window closed, or when
        ``force_counters``; otherwise at the heartbeat."""
        assert self.publisher is not None and self.book is not None and self.source is not None
        book = self.book
        batch: SourceBatch | None = None
        try:
            batch = self.source.poll()
        except Exception as error:  # a sensor failure must not end the daemon
            before = book.poll_error
            message = book.on_poll_error(error)
            if message != before:
                log.warning("source poll failed: %s", message)
            closed = book.close_ready()  # a window's deadline passes even while the source fails
        else:
            fresh, closed = book.on_batch(batch)
            if fresh and self.stream_samples:  # nobody takes samples: nothing to encode
                # All channels at once: one wake-up of the I/O thread per poll, not one per message.
                header_t_ns = self.wall_clock()
                encode, accounts, samples = self.publisher.samples_message, book.accounts, batch.samples
                outgoing = []
                for name in fresh:
                    account = accounts[name]
                    t_ns, power_w = samples[name]
                    outgoing.append(encode(name, account.rate_hz, t_ns, power_w, account.energy_j, account.status,
                                           header_t_ns))
                self.publisher.send_all(outgoing)
            if self.recorder is not None:
                self.recorder.write_batch(batch)
        if self.counters is not None and (force_counters or closed or book.windows):  # else at the heartbeat
            self.counters.read(force=force_counters or bool(closed))
        if closed and self.core is not None:
            for window in closed:
                self.core.window_closed(window)
        return batch

    def _currents(self) -> tuple[str, ...]:
        """The currents to calibrate: with counters, the power-down currents too (they measure residency)."""
        if self.counters is None:
            return tuple(self.settings.currents)
        from hdeem_watch.calibrate.counter_model import currents_with_counters

        return currents_with_counters(self.settings.currents)

    def _edge_poll(self) -> SourceBatch | None:
        """A poll at a window edge (run.start, run.stop, baseline.measure): the counters are read too."""
        return self.poll_once(force_counters=True)

    def complete(self, pending: Pending, result: Any = None, error: tuple[str, str] | None = None) -> None:
        """Send a deferred control reply."""
        if self.control is not None:
            self.control.complete(pending, result, error=error)


def bind_failure(error: BaseException, endpoints: Mapping[str, str | None]) -> str:
    """The one line for a socket that would not bind, naming the flag of the endpoint that failed
    (ZeroMQ says which address in its message), or all of them when it does not say.

    Example:
        >>> bind_failure(OSError("Address already in use (addr='tcp://127.0.0.1:5591')"),
        ...              {"--pub": "ipc:///r/pub.sock", "--remote-control": "tcp://127.0.0.1:5591"})
        '--remote-control tcp://127.0.0.1:5591: cannot bind: Address already in use'
    """
    text = str(error)
    failed = re.search(r"\(addr='([^']*)'\)", text)
    reason = re.sub(r"\s*\(addr='[^']*'\)", "", text)
    if failed is not None:
        for flag, endpoint in endpoints.items():
            if endpoint and endpoint == failed.group(1):
                return f"{flag} {endpoint}: cannot bind: {reason}"
    named = " / ".join(e for e in endpoints.values() if e)
    return f"cannot bind {named}: {reason}"


def _window_shape(book: NodeState) -> tuple[int, int]:
    """How many windows are open and how many of them are closing: a change of either may change
    the poll period (a closing window waits for the sample at its end, at full rate)."""
    windows = book.windows
    return len(windows), sum(1 for w in windows if w.closing)
