"""The one stream subscriber's decisions: discovery, late join, reconnect, gap tracking.

A client is given a daemon's *control* endpoint; the daemon's ``status`` names its stream (PUB)
endpoint (:mod:`~hdeem_watch.wire.discovery` picks the one reachable from here). The stream sends
some things only on change (runs, calibration, baselines): a late joiner gets ``calib`` and
``baseline`` from the publisher's last-value cache the moment it subscribes, and the rest with the
control ops of :data:`LATE_JOIN_OPS`. When the stream goes quiet the control endpoint is probed
(at most once per probe interval): unreachable → reconnecting; back → the late-join state is
fetched anew and, when the daemon now names another stream endpoint, the stream re-subscribed.
Every accepted message's sequence number goes through one
:class:`~hdeem_watch.wire.protocol.GapTracker` (messages missed, daemon restarts).

:class:`StreamFollower` holds these decisions and no socket, thread or clock: the TUI's feed thread
(:mod:`hdeem_watch.tui.feed`) and the MetricQ source's asyncio reader
(:mod:`hdeem_watch.metricq.stream`) drive it with the frames they receive, the status replies they
get and the time they read, and do the I/O it asks for.

Example:
    >>> import numpy as np
    >>> from hdeem_watch.wire.protocol import encode_samples
    >>> follower = StreamFollower("ipc:///run/hw/control.sock")
    >>> follower.probe_due(0, subscribed=False)
    True
    >>> plan = follower.plan({"node": "n1", "endpoints": {"pub": "ipc:///run/hw/pub.sock"}}, 0, subscribed=False)
    >>> plan.subscribe, plan.subscription, plan.late_join, plan.history
    ('ipc:///run/hw/pub.sock', b'hw1/n1/', True, True)
    >>> frames = encode_samples("n1", "DDR_AB", seq=4, rate_hz=100.0, t_wall_ns=np.array([1]),
    ...                         power_w=np.array([2.0]), energy_j=1.0, status="ok")
    >>> follower.accept(frames, 10).channel, follower.gaps.missed
    ('DDR_AB', 0)
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from hdeem_watch.wire.discovery import is_local_host, stream_endpoint, unreachable_stream
from hdeem_watch.wire.protocol import (
    GapTracker,
    Message,
    ProtocolError,
    decode,
    subscription,
)

#: What a subscriber asks the control endpoint for when it joins (or rejoins) a daemon: what the
#: stream sends only on change. ``calib`` and ``baseline`` also come from the last-value cache.
LATE_JOIN_OPS = ("runs.list", "calib.get", "baseline.get")
#: How often a quiet or unreachable daemon's control endpoint is asked for its status.
PROBE_INTERVAL_NS = 1_000_000_000


@dataclass(frozen=True)
class StreamPlan:
    """What the driver does after a ``status`` reply.

    Attributes:
        stream: the stream endpoint reachable from here ("" when the status names none).
        subscribe: connect a new SUB socket to this endpoint (closing the old one), or None.
        subscription: the prefix to subscribe to (the node's topics, or everything).
        close: close the SUB socket: the stream cannot be reached from here (:attr:`why_not`).
        late_join: fetch :data:`LATE_JOIN_OPS` now (the daemon was just reached).
        history: the late-join state is the daemon's history (first contact), not what was missed.
        why_not: why the stream cannot be reached, or None.
    """

    stream: str
    subscribe: str | None
    subscription: bytes
    close: bool
    late_join: bool
    history: bool
    why_not: str | None


@dataclass(frozen=True)
class Connection:
    """A connection state to show and why (``connecting``, ``reconnecting``)."""

    state: str
    detail: str


class StreamFollower:
    """Decisions of one subscriber of one daemon (or of fixed stream endpoints).

    Args:
        control_endpoint: the daemon's control endpoint; None when the stream endpoints are given
            directly (no discovery, no late join: the last-value cache is all a joiner gets).
        kinds: the message kinds taken (others are dropped before decoding); None: every kind.
        stale_after_ns: silence after which the stream is quiet: the daemon is probed, and a
            sequence jump across the silence is not counted as loss (the silence showed).
        probe_interval_ns: least time between two probes.
        is_local: whether a host is this machine (an ``ipc://`` stream of another host is unreachable).
    """

    def __init__(self, control_endpoint: str | None, *, kinds: Collection[str] | None = None,
                 stale_after_ns: int = 3_000_000_000, probe_interval_ns: int = PROBE_INTERVAL_NS,
                 is_local: Callable[[str], bool] = is_local_host) -> None:
        self.control_endpoint = control_endpoint
        self.kinds = frozenset(kinds) if kinds is not None else None
        self._kind_bytes = {kind.encode() for kind in self.kinds} if self.kinds is not None else None
        self.stale_after_ns = int(stale_after_ns)
        self.probe_interval_ns = int(probe_interval_ns)
        self.is_local = is_local
        self.gaps = GapTracker(silence_ns=self.stale_after_ns)
        self.messages = 0
        self.bad_messages = 0
        self.last_error = ""
        self.last_rx_ns: int | None = None
        self.stream = ""
        self.reachable = False
        self.late_joined = False
        self._last_probe_ns: int | None = None
        self._subscribed_ns = 0

    # ------------------------------------------------------------------ the stream

    def accept(self, frames: Sequence[Any], now_ns: int) -> Message | None:
        """The decoded message of ``frames`` received at ``now_ns`` (monotonic), or None when it is
        of a kind not taken or malformed (counted in :attr:`bad_messages`, reason in
        :attr:`last_error`). Its sequence number is tracked in :attr:`gaps`."""
        if self._kind_bytes is not None and len(frames) == 3:
            parts = bytes(frames[0]).split(b"/")
            if len(parts) > 2 and parts[2] not in self._kind_bytes:
                return None
        try:
            message = decode(frames)
        except ProtocolError as error:
            self.bad_messages += 1
            self.last_error = str(error)
            return None
        self.gaps.observe(message.topic, message.seq, now_ns)
        self.last_rx_ns = now_ns
        self.messages += 1
        return message

    def quiet(self, now_ns: int) -> bool:
        """Whether nothing arrived for longer than the stale time (or nothing yet)."""
        return self.last_rx_ns is None or now_ns - self.last_rx_ns > self.stale_after_ns

    # ------------------------------------------------------------------ discovery

    def probe_due(self, now_ns: int, *, subscribed: bool) -> bool:
        """Whether to ask the control endpoint for ``status`` now (not subscribed, not reachable, or
        quiet; at most once per probe interval). A True answer counts as the probe."""
        if self.control_endpoint is None:
            return False
        if subscribed and self.reachable and not self.quiet(now_ns):
            return False
        if self._last_probe_ns is not None and now_ns - self._last_probe_ns < self.probe_interval_ns:
            return False
        self._last_probe_ns = now_ns
        return True

    def unreachable(self, reason: str, *, state: str, subscribed: bool) -> Connection:
        """The control endpoint did not answer: the state to show (``connecting`` before the
        first contact, else ``reconnecting``); the next answer triggers a late join."""
        self.reachable = False
        return Connection("connecting" if state == "connecting" and not subscribed else "reconnecting", reason)

    def plan(self, status: Mapping[str, Any], now_ns: int, *, subscribed: bool) -> StreamPlan:
        """What to do with the daemon's ``status`` reply: (re)subscribe, close, late join."""
        endpoints = status.get("endpoints")
        control = self.control_endpoint or ""
        stream = stream_endpoint(control, endpoints if isinstance(endpoints, Mapping) else {}, is_local=self.is_local)
        why_not = (unreachable_stream(control, stream, is_local=self.is_local) if stream
                   else "its status names no stream endpoint")
        node = status.get("node")
        subscribe = None
        if why_not is None and (not subscribed or stream != self.stream):
            subscribe = stream
            self.stream = stream
            self._subscribed_ns = now_ns
        late_join = not self.reachable
        history = not self.late_joined
        self.reachable = True
        if late_join:
            self.late_joined = True
        return StreamPlan(stream=stream, subscribe=subscribe,
                          subscription=subscription(node if isinstance(node, str) and node and "/" not in node
                                                    else None),
                          close=why_not is not None, late_join=late_join, history=history, why_not=why_not)

    def connection(self, plan: StreamPlan, now_ns: int, *, state: str, refused: str | None) -> Connection | None:
        """The state to show once the plan is carried out, or None to leave it (the stream flows).

        Args:
            plan: the plan of the status reply.
            now_ns: monotonic now.
            state: the state shown now.
            refused: why the stream's security handshake failed, or None.
        """
        if plan.why_not is not None:
            return Connection("connecting", f"control answers, but {plan.why_not}")
        if refused is not None and self.last_rx_ns is None:
            return Connection("connecting", f"control answers, but its stream {plan.stream} refused: {refused}")
        if self.last_rx_ns is None and now_ns - self._subscribed_ns > self.stale_after_ns:
            return Connection("connecting", f"control answers, but nothing arrives from its stream {plan.stream} "
                                            "(firewall? another host?)")
        if state == "reconnecting":
            return Connection("connecting", "daemon back; waiting for its stream")
        return None
