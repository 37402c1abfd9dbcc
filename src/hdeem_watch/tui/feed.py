"""Background subscribers: one thread per daemon turns the wire stream into snapshots.

Each :class:`NodeFeed` drives the one subscriber core (:class:`~hdeem_watch.wire.subscriber.StreamFollower`):
it asks the daemon's control endpoint for ``status`` (which names its PUB endpoint), subscribes to
the node's topics, fetches what a late joiner needs (``runs.list``, ``calib.get``,
``baseline.get``), and then feeds every message into a
:class:`~hdeem_watch.tui.model.NodeModel`. A few times a second it builds an immutable
:class:`~hdeem_watch.tui.snapshot.NodeSnapshot` and stores it as :attr:`NodeFeed.latest`
(replaceable: only the newest matters). The app never touches sockets.

When the stream goes quiet the feed probes the control endpoint: unreachable → ``reconnecting``
(ZeroMQ reconnects the SUB socket by itself when the daemon comes back on the same endpoint; a
different PUB endpoint is re-subscribed); back again → the late-join state is fetched anew.

Control requests from the UI (e.g. ``baseline.measure``, whose reply comes only when the
measurement ends) run in short-lived threads with their own sockets (a ZeroMQ socket belongs to
one thread), so the stream never waits for them. Their outcome comes back as a message
(:mod:`~hdeem_watch.tui.messages`) through the feed's queue; the feed thread, the model's only
owner, shows it as the notice.

What the app shows (:class:`~hdeem_watch.tui.messages.ViewSettings`) is immutable: the app swaps
in a new one whole and the feeds read it once per snapshot.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import zmq

from hdeem_watch.tui.messages import (
    RequestDone,
    RequestFailed,
    RequestOutcome,
    RequestSent,
    RequestUnanswered,
    ViewSettings,
)
from hdeem_watch.tui.model import NodeModel
from hdeem_watch.tui.snapshot import NodeSnapshot
from hdeem_watch.wire.client import ControlClient, ControlError, DaemonUnreachable
from hdeem_watch.wire.discovery import is_local_host
from hdeem_watch.wire.handshake import HandshakeWatch
from hdeem_watch.wire.keys import ClientCurve, secure_client
from hdeem_watch.wire.subscriber import LATE_JOIN_OPS, StreamFollower, StreamPlan

#: Snapshot period of a node that is not focused (its snapshot only feeds the health bar).
BACKGROUND_PERIOD_NS = 500_000_000
#: Timeout of a control request from the UI (plus its ``seconds`` argument, if any).
REQUEST_TIMEOUT_S = 5.0
#: How many queued messages one wake-up handles before building a snapshot (bounds latency).
DRAIN_LIMIT = 5000


class NodeFeed(threading.Thread):
    """Subscriber thread of one daemon.

    Args:
        endpoint: the daemon's control endpoint.
        index: this feed's position (compared with :attr:`ViewSettings.focus`).
        view: shared view settings.
        context: ZeroMQ context (default: the process's shared one).
        snapshot_hz: how often a snapshot is built.
        stale_after_s: silence after which the node is stale and the daemon is probed.
        control_timeout_s: timeout of each control call.
        clock: monotonic clock in ns (injectable).
        wall_clock: wall clock in ns (injectable).
        is_local: whether a host is this machine (an ``ipc://`` stream of another host is unreachable).
        curve: the CURVE keys for TCP endpoints (None: no CURVE).
    """

    def __init__(
        self,
        endpoint: str,
        *,
        index: int = 0,
        view: ViewSettings | None = None,
        context: zmq.Context[Any] | None = None,
        snapshot_hz: float = 10.0,
        stale_after_s: float = 3.0,
        control_timeout_s: float = 1.0,
        clock: Callable[[], int] = time.monotonic_ns,
        wall_clock: Callable[[], int] = time.time_ns,
        is_local: Callable[[str], bool] = is_local_host,
        curve: ClientCurve | None = None,
    ) -> None:
        super().__init__(name=f"hdeem-watch-feed-{index}", daemon=True)
        self.endpoint = endpoint
        self.index = index
        self.view = view or ViewSettings()
        self._context = context or zmq.Context.instance()
        self._period_ns = int(1e9 / max(snapshot_hz, 0.5))
        self._stale_ns = int(stale_after_s * 1e9)
        self._clock = clock
        self._wall = wall_clock
        self._follower = StreamFollower(endpoint, stale_after_ns=self._stale_ns, is_local=is_local)
        self.model = NodeModel(endpoint, stale_after_s=stale_after_s)
        self.curve = curve
        self._control = self._client(control_timeout_s)
        self._sub: zmq.Socket[Any] | None = None
        self._sub_watch: HandshakeWatch | None = None
        self._halt = threading.Event()
        self._wake = threading.Event()
        self._workers: list[threading.Thread] = []
        self._outcomes: queue.SimpleQueue[RequestOutcome] = queue.SimpleQueue()
        self.latest: NodeSnapshot = self._build(self._clock())
        self.messages = 0
        self.decode_errors = 0

    # ------------------------------------------------------------------ public

    def request(self, op: str, args: dict[str, Any] | None = None) -> None:
        """Send a control request from a short-lived thread of its own (replies such as
        ``baseline.measure`` come only after the measurement); the outcome comes back through the
        feed's queue and becomes the health bar's notice."""
        args = dict(args or {})
        seconds = args.get("seconds")
        measure_s = float(seconds) if isinstance(seconds, int | float) and not isinstance(seconds, bool) else None
        timeout_s = REQUEST_TIMEOUT_S + (measure_s or 0.0)
        self._tell(RequestSent(op, measure_s))
        worker = threading.Thread(
            target=self._request, args=(op, args, timeout_s), name=f"hdeem-watch-request-{op}", daemon=True
        )
        self._workers = [w for w in self._workers if w.is_alive()]
        self._workers.append(worker)
        worker.start()

    def _client(self, timeout_s: float) -> ControlClient:
        curve = self.curve
        if curve is None:
            return ControlClient(self.endpoint, timeout_s=timeout_s, context=self._context)
        return ControlClient(self.endpoint, timeout_s=timeout_s, context=self._context,
                             curve_server_key=curve.server_key, curve_client_keys=curve.client_keys)

    def _request(self, op: str, args: dict[str, Any], timeout_s: float) -> None:
        client = self._client(timeout_s)
        outcome: RequestOutcome
        try:
            result = client.call(op, args)
        except ControlError as error:
            outcome = RequestFailed(op, error.code, error.message)
        except DaemonUnreachable:
            outcome = RequestUnanswered(op, timeout_s)
        else:
            outcome = RequestDone(op, _short(result) if result else "")
        finally:
            client.close()
        self._tell(outcome)

    def _tell(self, outcome: RequestOutcome) -> None:
        """Queue a request's outcome for the feed thread and wake it."""
        self._outcomes.put(outcome)
        self._wake.set()

    def _take_outcomes(self) -> None:
        """Show the newest queued request outcome (feed thread only)."""
        while True:
            try:
                outcome = self._outcomes.get_nowait()
            except queue.Empty:
                return
            self.model.notice = outcome.notice

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop the thread and close its sockets."""
        self._halt.set()
        self._wake.set()
        if self.is_alive():
            self.join(timeout_s)

    # ------------------------------------------------------------------ thread

    def run(self) -> None:
        # One wake-up per snapshot: sleep until it is due (or the view changes), then take every
        # message ZeroMQ queued meanwhile. Far fewer wake-ups than one per message burst.
        next_snapshot = self._clock()
        try:
            while not self._halt.is_set():
                now = self._clock()
                if self._follower.probe_due(now, subscribed=self._sub is not None):
                    self._probe(now)
                wait_s = max(0, next_snapshot - self._clock()) / 1e9
                if self._wake.wait(wait_s):
                    self._wake.clear()
                    next_snapshot = self._clock()
                self._take_outcomes()
                if self._sub is not None:
                    self._drain()
                now = self._clock()
                if now >= next_snapshot:
                    self.latest = self._build(now)
                    # a node in the background only feeds the health bar's dot: fewer snapshots
                    focused = self.view.focus == self.index
                    period = self._period_ns if focused else max(self._period_ns, BACKGROUND_PERIOD_NS)
                    next_snapshot = max(next_snapshot + period, now)
        finally:
            self._close_sub()
            self._control.close()

    def wake(self) -> None:
        """Build the next snapshot now (the view changed)."""
        self._wake.set()

    def _build(self, now: int) -> NodeSnapshot:
        view = self.view
        return self.model.snapshot(
            now_mono_ns=now,
            now_wall_ns=self._wall(),
            window_s=view.window_s,
            width=view.width if view.focus == self.index else None,
        )

    def _drain(self) -> None:
        sub = self._sub
        assert sub is not None
        for _ in range(DRAIN_LIMIT):
            try:
                frames = sub.recv_multipart(zmq.NOBLOCK, copy=True)
            except zmq.Again:
                return
            received = self._clock()
            msg = self._follower.accept(frames, received)
            if msg is None:
                self.decode_errors += 1
                self.model.detail = f"bad message: {self._follower.last_error}"[:100]
                continue
            try:
                self.model.apply(msg, received)
            except Exception as error:  # a bad message must not end the feed
                self.decode_errors += 1
                self.model.detail = f"bad message: {error}"[:100]
                continue
            self.messages += 1

    def _probe(self, now: int) -> None:
        """Ask the daemon for status; (re)subscribe, late-join and show the connection as the
        subscriber core decides."""
        try:
            status = self._control.call("status")
        except (DaemonUnreachable, ControlError) as error:
            lost = self._follower.unreachable(_reason(error, self.endpoint), state=self.model.connection,
                                              subscribed=self._sub is not None)
            self.model.set_connection(lost.state, lost.detail)
            return
        if not isinstance(status, dict):
            return
        plan = self._follower.plan(status, now, subscribed=self._sub is not None)
        if plan.close:
            self._close_sub()
        elif plan.subscribe is not None:
            self._subscribe(plan)
        self.model.apply_status(status, wall_ns=self._wall())
        if plan.late_join:
            self._late_join(plan.history)
        shown = self._follower.connection(plan, now, state=self.model.connection, refused=self._stream_refused())
        if shown is not None:
            self.model.set_connection(shown.state, shown.detail)

    def _subscribe(self, plan: StreamPlan) -> None:
        self._close_sub()
        pub = plan.stream
        sub = self._context.socket(zmq.SUB)
        sub.setsockopt(zmq.LINGER, 0)
        sub.setsockopt(zmq.RCVHWM, 100_000)
        sub.setsockopt(zmq.RECONNECT_IVL, 100)
        sub.setsockopt(zmq.RECONNECT_IVL_MAX, 1000)
        sub.setsockopt(zmq.SUBSCRIBE, plan.subscription)
        if self.curve is not None and pub.startswith("tcp://"):
            secure_client(sub, self.curve.server_key, self.curve.client_keys)
        if pub.startswith("tcp://"):  # a refused handshake is otherwise retried silently forever
            self._sub_watch = HandshakeWatch(sub, curve=self.curve is not None)
        sub.connect(pub)
        self._sub = sub

    def _stream_refused(self) -> str | None:
        """Why the stream's security handshake failed, while nothing arrived (None: it did not)."""
        if self._sub_watch is None or self.model.last_rx_mono_ns is not None:
            return None
        self._sub_watch.read()
        return self._sub_watch.failure

    def _close_sub(self) -> None:
        if self._sub_watch is not None:
            self._sub_watch.close()
            self._sub_watch = None
        if self._sub is not None:
            self._sub.close(linger=0)
            self._sub = None

    def _late_join(self, history: bool) -> None:
        """Fetch what the stream only sends on change: runs, calibration, baselines.

        The runs found at the first connection are the daemon's history (marked so: a headless
        printer does not report them as new); after a reconnection they are the runs missed.
        """
        apply: dict[str, Callable[[Any], None]] = {
            "runs.list": lambda result: self._apply_runs(result, history=history),
            "calib.get": self.model.apply_calib,
            "baseline.get": self.model.apply_baselines,
        }
        for op in LATE_JOIN_OPS:
            try:
                result = self._control.call(op)
            except (DaemonUnreachable, ControlError):
                continue
            if result is not None:
                apply[op](result)

    def _apply_runs(self, result: Any, *, history: bool = False) -> None:
        runs = result.get("runs") if isinstance(result, dict) else result
        if isinstance(runs, list):
            finished = [r for r in runs if isinstance(r, dict) and not _running(r)]
            # runs.list is newest first; the model keeps them oldest first
            self.model.add_runs(list(reversed(finished)), history=history)


def _running(run: dict[str, Any]) -> bool:
    stop = run.get("t_stop_ns", run.get("stop_ns", 0))
    return run.get("state") == "running" or stop is None


def _short(result: Any) -> str:
    if isinstance(result, dict):
        items = [f"{k}={v}" for k, v in result.items() if isinstance(v, str | int | float)][:3]
        return ", ".join(items)
    return str(result)[:60]


class FeedHub:
    """All feeds of one UI, with their shared view settings.

    Args:
        endpoints: control endpoints, one per daemon.
        snapshot_hz: how often each feed builds a snapshot.
        **options: passed on to each :class:`NodeFeed`.
    """

    def __init__(self, endpoints: Sequence[str], *, snapshot_hz: float = 10.0, **options: Any) -> None:
        self.view = ViewSettings()
        self.feeds = [
            NodeFeed(ep, index=i, view=self.view, snapshot_hz=snapshot_hz, **options) for i, ep in enumerate(endpoints)
        ]

    def start(self) -> None:
        """Start every feed thread."""
        for feed in self.feeds:
            feed.start()

    def stop(self) -> None:
        """Stop every feed thread."""
        for feed in self.feeds:
            feed._halt.set()
            feed._wake.set()
        for feed in self.feeds:
            feed.stop()

    def snapshots(self) -> list[NodeSnapshot]:
        """The newest snapshot of every node, in endpoint order."""
        return [feed.latest for feed in self.feeds]

    def set_view(self, *, focus: int, window_s: float, width: int) -> None:
        """Tell the feeds what the app shows: a new immutable view, swapped in whole (a changed
        view is served at once)."""
        view = ViewSettings(window_s=window_s, width=width, focus=focus)
        if view == self.view:
            return
        self.view = view
        for feed in self.feeds:
            feed.view = view
            feed.wake()

    def request(self, index: int, op: str, args: dict[str, Any] | None = None) -> None:
        """Queue a control request to daemon ``index``."""
        self.feeds[index].request(op, args)


def snapshot_age_s(snapshot: NodeSnapshot, now_mono_ns: int) -> float:
    """How old a snapshot is (the app flags a feed that stopped producing)."""
    return (now_mono_ns - snapshot.built_mono_ns) / 1e9 if snapshot.built_mono_ns else math.nan


def _reason(error: Exception, endpoint: str) -> str:
    """A short reason without the endpoint (the health bar shows that already)."""
    text = str(error)
    if text.startswith(endpoint):
        text = text[len(endpoint) :].lstrip(": ")
    return text[:200] or "unreachable"
