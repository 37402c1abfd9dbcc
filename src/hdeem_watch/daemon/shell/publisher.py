"""The daemon's stream socket: sequence numbers, never-blocking sends, a last-value cache.

An XPUB socket behaves like PUB for subscribers and additionally tells the daemon about new
subscriptions. Sends never block: each subscriber has its own queue of ``sndhwm`` messages and a
subscriber that does not keep up loses messages (it sees the gap in ``seq``) while the others go
on at full rate. When a subscription arrives that covers the ``calib`` or ``baseline`` topic, the
latest message of that topic is published again at once, so a late joiner has the current
calibration and baselines without waiting for the periodic re-publication (a last-value cache).

Example:
    >>> import zmq
    >>> pub = Publisher(zmq.Context.instance(), "inproc://doc", node="n1")
    >>> pub.publish("status", {"uptime_s": 1.0})
    True
    >>> pub.close()
"""

from __future__ import annotations

import logging
import os
import sys
import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import zmq

from hdeem_watch.daemon.shell.endpoints import bind, bind_endpoint, is_loopback
from hdeem_watch.errors import InputError
from hdeem_watch.wire import protocol

__all__ = ["CACHED_KINDS", "MAX_SUBSCRIPTIONS", "Publisher", "bind_endpoint", "daemon_context"]

log = logging.getLogger("hdeem_watch.daemon")

_NOBLOCK = int(zmq.NOBLOCK)
_MORE_NOBLOCK = int(zmq.SNDMORE) | int(zmq.NOBLOCK)

#: Topics whose latest message is cached and re-sent to new subscribers.
CACHED_KINDS = ("calib", "baseline")
#: Most distinct subscription prefixes held at once (a TUI holds a handful). libzmq keeps every
#: prefix a peer sends until that peer leaves (~0.8 KB each; 200,000 of them once took 520 MiB)
#: and an XPUB cannot tell which peer sent which, so beyond this bound every stream connection is
#: dropped (subscribers reconnect and subscribe again by themselves) and a warning is logged.
MAX_SUBSCRIPTIONS = 10_000


def daemon_context() -> zmq.Context[Any]:
    """A ZeroMQ context whose I/O thread runs under ``SCHED_BATCH`` (``ZMQ_THREAD_SCHED_POLICY``).

    A woken ``SCHED_BATCH`` thread does not preempt the running one. Without it, the first message
    of a poll woke the I/O thread on the loop's own core, where it preempted the loop, wrote that one
    message and slept, and the next message woke it again: about 3.8 wake-ups and 3 preemptions of
    the loop per poll with 4 subscribers. Under ``SCHED_BATCH`` it wakes once a poll and writes all
    of the poll's messages together. It does not preempt the node's applications either. Linux only:
    elsewhere the option is left alone.
    """
    context: zmq.Context[Any] = zmq.Context()
    if sys.platform.startswith("linux"):
        context.set(zmq.THREAD_SCHED_POLICY, os.SCHED_BATCH)
    return context


class Publisher:
    """Publishes protocol-v1 messages of one node on an XPUB socket.

    Args:
        context: the ZeroMQ context.
        endpoint: where to bind.
        node: node name used in every topic and header.
        sndhwm: per-subscriber queue length in messages.
        secure: applied to the socket before it binds (CURVE, :mod:`hdeem_watch.daemon.shell.security`).
        max_subscriptions: the bound on distinct subscription prefixes (:data:`MAX_SUBSCRIPTIONS`).
        clock: monotonic seconds (rate limit of the warnings).

    Attributes:
        sent: messages handed to ZeroMQ.
        dropped: messages ZeroMQ refused at once (``EAGAIN``; not expected with XPUB).
        subscriptions: subscription messages seen.
        resets: times every connection was dropped for too many subscriptions.
        prefixes: subscribed prefixes (a prefix leaves when its last subscriber unsubscribes or goes away).
    """

    def __init__(self, context: zmq.Context[Any], endpoint: str, *, node: str, sndhwm: int = 20_000,
                 secure: Callable[[zmq.Socket[Any]], None] | None = None,
                 max_subscriptions: int = MAX_SUBSCRIPTIONS, clock: Callable[[], float] = time.monotonic) -> None:
        self.node = node
        self.socket = context.socket(zmq.XPUB)
        if secure is not None:
            secure(self.socket)
        elif not is_loopback(endpoint):
            log.warning("stream %s: TCP without CURVE on a non-loopback address: anyone who can reach it "
                        "reads every sample, unencrypted (allowed by allow_insecure_tcp)", endpoint)
        self.socket.setsockopt(zmq.SNDHWM, int(sndhwm))
        # Subscriptions wait in the peer's socket instead of piling up here between two reads.
        self.socket.setsockopt(zmq.RCVHWM, 1000)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.setsockopt(zmq.XPUB_VERBOSE, 1)
        binding = bind(self.socket, endpoint)
        self.endpoint, self._ipc = binding.endpoint, binding.ipc
        self._seq = protocol.SequenceCounter()
        self._cache: dict[str, list[bytes]] = {}
        self._encoders: dict[str, protocol.SamplesEncoder] = {}
        self._max_subscriptions = int(max_subscriptions)
        self._clock = clock
        self._warned_at = -1e9
        self.sent = 0
        self.dropped = 0
        self.subscriptions = 0
        self.resets = 0
        self.prefixes: set[bytes] = set()

    def _send(self, frames: list[bytes]) -> bool:
        return self.send_all([frames]) == 1

    def publish(self, kind: str, body: Mapping[str, Any], *, t_ns: int | None = None) -> bool:
        """Publish a non-sample message (``status``, ``run``, ``calib``, ``baseline``)."""
        topic = protocol.topic(self.node, kind)
        header = dict(body)
        header.update(
            {"v": protocol.VERSION, "seq": self._seq.next(topic), "node": self.node,
             "t_ns": protocol.now_ns() if t_ns is None else int(t_ns)}
        )
        frames = protocol.encode(topic, header)
        if kind in CACHED_KINDS:
            self._cache[topic] = frames
        return self._send(frames)

    def publish_samples(
        self,
        channel: str,
        *,
        rate_hz: float,
        t_wall_ns: np.ndarray,
        power_w: np.ndarray,
        energy_j: float,
        status: str,
        t_ns: int | None = None,
    ) -> bool:
        """Publish one samples batch of one channel."""
        return self._send(self.samples_message(channel, rate_hz, t_wall_ns, power_w, energy_j, status,
                                               protocol.now_ns() if t_ns is None else int(t_ns)))

    def samples_message(self, channel: str, rate_hz: float, t_wall_ns: np.ndarray, power_w: np.ndarray,
                        energy_j: float, status: str, t_ns: int) -> list[bytes]:
        """The frames of the next samples batch of ``channel`` (takes its sequence number; not sent).

        The poll's hot path (positional arguments, header time given), encoded by the channel's
        :class:`~hdeem_watch.wire.protocol.SamplesEncoder`. The daemon encodes every channel of a
        poll first and hands them to :meth:`send_all` at once: back-to-back sends wake ZeroMQ's I/O
        thread (and each subscriber) once per poll instead of once per message.
        """
        encoder = self._encoders.get(channel)
        if encoder is None or encoder.rate_hz != rate_hz:
            encoder = self._encoders[channel] = protocol.SamplesEncoder(self.node, channel, rate_hz)
        return encoder.frames(self._seq.next(encoder.topic), t_ns, t_wall_ns, power_w, energy_j, status)

    def send_all(self, messages: list[list[bytes]]) -> int:
        """Send several messages back to back (in order); return how many were handed to ZeroMQ."""
        send, sent = self.socket.send, 0
        for topic, header, payload in messages:
            try:
                send(topic, _MORE_NOBLOCK)
            except zmq.Again:  # XPUB drops instead of blocking; kept for a PUB-like socket
                self.dropped += 1
                continue
            send(header, _MORE_NOBLOCK)
            send(payload, _NOBLOCK, copy=len(payload) < 65536)
            sent += 1
        self.sent += sent
        return sent

    def handle_subscriptions(self) -> int:
        """Read pending subscription messages; re-send cached topics a new subscription covers.

        Beyond ``max_subscriptions`` distinct prefixes every connection is dropped (see
        :data:`MAX_SUBSCRIPTIONS`).
        """
        handled = 0
        resend: set[str] = set()
        while True:
            try:
                message = self.socket.recv(flags=zmq.NOBLOCK)
            except zmq.Again:
                break
            handled += 1
            if not message:
                continue
            prefix = message[1:]
            if message[0] == 0:  # the last subscriber of this prefix left
                self.prefixes.discard(prefix)
                continue
            if message[0] != 1:
                continue
            self.subscriptions += 1
            self.prefixes.add(prefix)
            if len(self.prefixes) > self._max_subscriptions:
                self._drop_connections()
                return handled
            for topic in self._cache:
                if topic.encode().startswith(prefix):
                    resend.add(topic)
        for topic in sorted(resend):
            frames = list(self._cache[topic])
            # A re-send is a new message of its topic: fresh sequence number, same body.
            header = protocol.loads_object(frames[1])
            header["seq"] = self._seq.next(topic)
            self._send([frames[0], protocol.dumps(header), frames[2]])
        return handled

    def _drop_connections(self) -> None:
        """Unbind and bind again: libzmq ends every connection of the endpoint and frees its subscriptions."""
        self.resets += 1
        now = self._clock()
        if now - self._warned_at >= 60.0:
            self._warned_at = now
            log.warning("stream %s: more than %d distinct subscriptions; the rest are refused by dropping every "
                        "stream connection (subscribers reconnect by themselves; %d resets so far)",
                        self.endpoint, self._max_subscriptions, self.resets)
        self.socket.unbind(self.endpoint)
        while True:  # what is still queued belonged to the dropped connections
            try:
                self.socket.recv(flags=zmq.NOBLOCK)
            except zmq.Again:
                break
        self.prefixes.clear()
        self._rebind()

    def _rebind(self, timeout_s: float = 2.0) -> None:
        """Bind the endpoint again once libzmq's I/O thread has let go of it.

        The old listener closes asynchronously: until it has, its TCP port is in use and a probe of
        its ipc file still finds it listening. libzmq (4.3) leaves the old ipc file in place and
        replaces it at the new bind, so nothing waits for the file to go (waiting for that stalled
        the poll loop 2 s at every reset).
        """
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                self._ipc = bind(self.socket, self.endpoint).ipc
                return
            except zmq.ZMQError as error:
                if error.errno != zmq.EADDRINUSE or time.monotonic() >= deadline:
                    raise
            except InputError:  # the old listener still answers the live-socket probe
                if time.monotonic() >= deadline:
                    raise
            time.sleep(0.01)

    def watched(self, kind: str) -> bool:
        """Whether some subscriber receives messages of ``kind`` (e.g. ``"samples"``)."""
        base = protocol.subscription(self.node, kind)  # every topic of the kind starts with it
        return any(base.startswith(prefix) or prefix.startswith(base) for prefix in self.prefixes)

    def close(self) -> None:
        """Close the socket (pending messages are dropped: LINGER 0) and remove its ipc file if still ours."""
        self.socket.close(linger=0)
        if self._ipc is not None:
            self._ipc.unlink_if_ours()
