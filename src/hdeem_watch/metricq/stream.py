"""An asynchronous subscriber of one or more daemons' streams (ZeroMQ SUB, asyncio).

It is a plain subscriber: the daemon's PUB socket never waits for it (a slow subscriber loses
messages at the high-water mark, seen here as sequence gaps), so nothing this process does can
block the daemon. ZeroMQ reconnects by itself when a daemon restarts; the restart shows as sequence
numbers going back. Which messages are taken, their decoding and the gap tracking are the one
subscriber core's (:class:`~hdeem_watch.wire.subscriber.StreamFollower`, given the stream
endpoints directly: a late joiner gets ``calib`` and ``baseline`` from the daemon's last-value
cache the moment it subscribes).

Example::

    reader = StreamReader(["ipc:///run/hdeem-watch/pub.sock"])
    messages = await reader.receive(timeout_s=1.0)   # [] after a second of silence
    reader.close()
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Sequence
from typing import Any

import zmq

from hdeem_watch.wire import protocol
from hdeem_watch.wire.subscriber import StreamFollower

log = logging.getLogger("hdeem-watch.metricq")

#: The kinds the source uses (``status`` and ``run`` are not subscribed to).
KINDS = ("samples", "baseline", "calib")
#: Messages a slow reader lets ZeroMQ queue before dropping (about 10 s of 8 nodes' samples).
RECEIVE_HWM = 20_000


class StreamReader:
    """Subscribes to ``samples``, ``baseline`` and ``calib`` of every node at ``endpoints``.

    The socket is drained without blocking every ``drain_interval_s`` (the daemon publishes in bursts
    every 40 ms), which costs far less than waking the event loop for every message.

    Args:
        endpoints: the daemons' pub endpoints (ipc or tcp).
        drain_interval_s: how often waiting messages are taken.
        curve_server_key: the daemons' CURVE public key (Z85) when they run with CURVE.
        curve_client_keys: ``(public, secret)`` of this client (default: an ephemeral pair).
    """

    def __init__(self, endpoints: Sequence[str], *, drain_interval_s: float = 0.04,
                 curve_server_key: bytes | None = None,
                 curve_client_keys: tuple[bytes, bytes] | None = None) -> None:
        if not endpoints:
            raise ValueError("no stream endpoint")
        self.drain_interval_s = drain_interval_s
        self._context: zmq.Context[Any] = zmq.Context()
        self._socket: zmq.Socket[Any] = self._context.socket(zmq.SUB)
        self._socket.setsockopt(zmq.RCVHWM, RECEIVE_HWM)
        self._socket.setsockopt(zmq.LINGER, 0)
        if curve_server_key is not None:
            from hdeem_watch.wire.keys import secure_client

            secure_client(self._socket, curve_server_key, curve_client_keys)
        # Kinds sit after the node in the topic, so every message is subscribed to and filtered here
        # (the others are a heartbeat a second and the rare run events).
        self._socket.setsockopt(zmq.SUBSCRIBE, protocol.subscription())
        for endpoint in endpoints:
            self._socket.connect(endpoint)
        self.follower = StreamFollower(None, kinds=KINDS)
        self.gaps = self.follower.gaps

    def drain(self, limit: int = 10_000) -> list[protocol.Message]:
        """Every waiting message of a used kind (at most ``limit`` read), without blocking."""
        out: list[protocol.Message] = []
        for _ in range(limit):
            try:
                frames = self._socket.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                break
            bad = self.follower.bad_messages
            message = self.follower.accept(frames, time.monotonic_ns())
            if message is not None:
                out.append(message)
            elif self.follower.bad_messages != bad:
                log.warning("ignored a malformed stream message: %s", self.follower.last_error)
        return out

    @property
    def bad_messages(self) -> int:
        """Malformed messages ignored so far."""
        return self.follower.bad_messages

    async def receive(self, timeout_s: float) -> list[protocol.Message]:
        """The next messages (a non-empty list), or an empty list when none came within ``timeout_s``."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while True:
            messages = self.drain()
            if messages or loop.time() >= deadline:
                return messages
            await asyncio.sleep(min(self.drain_interval_s, max(0.0, deadline - loop.time())))

    def close(self) -> None:
        """Close the socket and its context."""
        self._socket.close(linger=0)
        self._context.term()
