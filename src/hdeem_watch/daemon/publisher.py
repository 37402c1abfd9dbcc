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

import math
import os
import stat
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import zmq

from hdeem_watch.daemon import protocol
from hdeem_watch.daemon.client import ipc_path

_NOBLOCK = int(zmq.NOBLOCK)
_MORE_NOBLOCK = int(zmq.SNDMORE) | int(zmq.NOBLOCK)
#: The compiled ``Socket.send`` under pyzmq's Python wrapper (which only adds RADIO/SERVER options).
_RAW_SEND = getattr(zmq.backend, "Socket", zmq.Socket).send
_TIME_DTYPE = np.dtype(protocol.TIME_DTYPE)
_QUOTED_STATUS = {status: protocol._quoted(status) for status in ("ok", "stale", "overflow", "gap", "closed")}
_SAMPLE_DTYPE = np.dtype(protocol.SAMPLE_DTYPE)

#: Topics whose latest message is cached and re-sent to new subscribers.
CACHED_KINDS = ("calib", "baseline")


def bind_endpoint(sock: zmq.Socket[Any], endpoint: str) -> str:
    """Bind ``sock``; for ipc, create the directory (0750) and make the socket file 0660.

    Returns:
        The endpoint actually bound (``tcp://*:0`` resolves to its port).

    Raises:
        OSError: the directory cannot be created.
        zmq.ZMQError: the endpoint cannot be bound (in use, bad address).
    """
    path = ipc_path(endpoint)
    if path is not None:
        if len(str(path)) > 107:
            raise OSError(f"ipc path longer than 107 bytes: {path}")
        if not path.parent.exists():
            path.parent.mkdir(parents=True, mode=0o750)
    sock.bind(endpoint)
    bound = sock.getsockopt(zmq.LAST_ENDPOINT)
    if path is not None:
        os.chmod(path, stat.S_IRUSR | stat.S_IWUSR | stat.S_IRGRP | stat.S_IWGRP)
    return bound.decode() if isinstance(bound, bytes) else str(bound)


def samples_header_template(node: str, channel: str, rate_hz: float) -> str:
    """The samples header of one channel with its fixed fields filled in (exactly as
    :func:`protocol.encode_samples` formats them), left open: ``% (seq, t_ns, n, t0_ns, energy_j, status)``.
    """
    rate = float(rate_hz)
    fixed = {
        "node": protocol._quoted(node),
        "channel": protocol._quoted(channel),
        "rate": protocol._json_number(rate),
        "dt": str(round(1e9 / rate)) if rate > 0 and math.isfinite(rate) else "null",
    }
    node_q, channel_q, rate_s, dt_s = (fixed[key].replace("%", "%%") for key in ("node", "channel", "rate", "dt"))
    return (
        '{"v":' + str(protocol.VERSION) + ',"seq":%d,"node":' + node_q + ',"t_ns":%d,"channel":' + channel_q
        + ',"unit":"W","rate_hz":' + rate_s + ',"n":%d,"dtype":"<f8","t0_ns":%s,"dt_ns":' + dt_s
        + ',"energy_j":%s,"status":%s}'
    )


class Publisher:
    """Publishes protocol-v1 messages of one node on an XPUB socket.

    Args:
        context: the ZeroMQ context.
        endpoint: where to bind.
        node: node name used in every topic and header.
        sndhwm: per-subscriber queue length in messages.
        secure: applied to the socket before it binds (CURVE, :mod:`hdeem_watch.daemon.security`).

    Attributes:
        sent: messages handed to ZeroMQ.
        dropped: messages ZeroMQ refused at once (``EAGAIN``; not expected with XPUB).
        subscriptions: subscription messages seen.
    """

    def __init__(self, context: zmq.Context[Any], endpoint: str, *, node: str, sndhwm: int = 20_000,
                 secure: Callable[[zmq.Socket[Any]], None] | None = None) -> None:
        self.node = node
        self.socket = context.socket(zmq.XPUB)
        if secure is not None:
            secure(self.socket)
        self.socket.setsockopt(zmq.SNDHWM, int(sndhwm))
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.setsockopt(zmq.XPUB_VERBOSE, 1)
        self.endpoint = bind_endpoint(self.socket, endpoint)
        self._seq = protocol.SequenceCounter()
        self._cache: dict[str, list[bytes]] = {}
        #: Per channel: topic, topic bytes, rate and the header template of its samples messages.
        self._sample_topics: dict[str, tuple[str, bytes, float, str]] = {}
        self.sent = 0
        self.dropped = 0
        self.subscriptions = 0
        #: Subscribed prefixes (a prefix leaves when its last subscriber unsubscribes or goes away).
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

        The poll's hot path (positional arguments, header time given). The daemon encodes every
        channel of a poll first and hands them to :meth:`send_all` at once: back-to-back sends wake
        ZeroMQ's I/O thread (and each subscriber) once per poll instead of once per message, which is
        most of the cost of a send on a virtual machine.
        """
        known = self._sample_topics.get(channel)
        if known is None or known[2] != rate_hz:
            topic = protocol.samples_topic(self.node, channel)
            known = self._sample_topics[channel] = (topic, topic.encode(),
                                                    rate_hz, samples_header_template(self.node, channel, rate_hz))
        n = len(t_wall_ns)
        if (t_wall_ns.dtype is _TIME_DTYPE and power_w.dtype is _SAMPLE_DTYPE and t_wall_ns.ndim == 1
                and power_w.shape == t_wall_ns.shape):
            payload = t_wall_ns.tobytes() + power_w.tobytes()
            t0 = str(t_wall_ns.item(0)) if n else "null"
        else:
            payload = protocol.pack_samples(t_wall_ns, power_w)
            n = len(payload) >> 4
            t0 = str(int(t_wall_ns[0])) if n else "null"
        energy_j = float(energy_j)
        header = known[3] % (
            self._seq.next(known[0]),
            t_ns,
            n,
            t0,
            repr(energy_j) if energy_j - energy_j == 0.0 else "null",  # finite
            _QUOTED_STATUS.get(status) or protocol._quoted(status),
        )
        return [known[1], header.encode(), payload]

    def send_all(self, messages: list[list[bytes]]) -> int:
        """Send several messages back to back (in order); return how many were handed to ZeroMQ."""
        sock, sent, send = self.socket, 0, _RAW_SEND
        for topic, header, payload in messages:
            try:
                send(sock, topic, _MORE_NOBLOCK)
            except zmq.Again:  # XPUB drops instead of blocking; kept for a PUB-like socket
                self.dropped += 1
                continue
            send(sock, header, _MORE_NOBLOCK)
            send(sock, payload, _NOBLOCK, len(payload) < 65536)
            sent += 1
        self.sent += sent
        return sent

    def handle_subscriptions(self) -> int:
        """Read pending subscription messages; re-send cached topics a new subscription covers."""
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

    def watched(self, kind: str) -> bool:
        """Whether some subscriber receives messages of ``kind`` (e.g. ``"samples"``)."""
        base = protocol.subscription(self.node, kind)  # every topic of the kind starts with it
        return any(base.startswith(prefix) or prefix.startswith(base) for prefix in self.prefixes)

    def close(self) -> None:
        """Close the socket (pending messages are dropped: LINGER 0)."""
        self.socket.close(linger=0)
