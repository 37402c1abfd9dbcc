"""An asynchronous subscriber of one or more daemons' streams (ZeroMQ SUB, asyncio).

It is a plain subscriber: the daemon's PUB socket never waits for it (a slow subscriber loses
messages at the high-water mark, seen here as sequence gaps), so nothing this process does can
block the daemon. ZeroMQ reconnects by itself when a daemon restarts; the restart shows as sequence
numbers going back (:class:`~hdeem_watch.daemon.protocol.GapTracker`).

Example::

    reader = StreamReader(["ipc:///run/hdeem-watch/pub.sock"])
    message = await reader.receive(timeout_s=1.0)   # None after a second of silence
    reader.close()
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

import zmq
import zmq.asyncio

from hdeem_watch.daemon import protocol

log = logging.getLogger("hdeem-watch.metricq")

#: The kinds the source uses (``status`` and ``run`` are not subscribed to).
KINDS = ("samples", "baseline", "calib")
#: Messages a slow reader lets ZeroMQ queue before dropping (about 10 s of 8 nodes' samples).
RECEIVE_HWM = 20_000


class StreamReader:
    """Subscribes to ``samples``, ``baseline`` and ``calib`` of every node at ``endpoints``.

    Args:
        endpoints: the daemons' pub endpoints (ipc or tcp).
        context: an asyncio ZeroMQ context (default: a new one, terminated by :meth:`close`).
        curve_server_key: the daemons' CURVE public key (Z85) when they run with CURVE.
    """

    def __init__(self, endpoints: Sequence[str], *, context: zmq.asyncio.Context | None = None,
                 curve_server_key: bytes | None = None) -> None:
        if not endpoints:
            raise ValueError("no stream endpoint")
        self._own_context = context is None
        self._context = context or zmq.asyncio.Context()
        self._socket: Any = self._context.socket(zmq.SUB)
        self._socket.setsockopt(zmq.RCVHWM, RECEIVE_HWM)
        self._socket.setsockopt(zmq.LINGER, 0)
        if curve_server_key is not None:
            from hdeem_watch.daemon.security import secure_client

            secure_client(self._socket, curve_server_key, None)
        # Kinds sit after the node in the topic, so every message is subscribed to and filtered here
        # (the others are a heartbeat a second and the rare run events).
        self._socket.setsockopt(zmq.SUBSCRIBE, protocol.subscription())
        for endpoint in endpoints:
            self._socket.connect(endpoint)
        self.gaps = protocol.GapTracker()
        self.bad_messages = 0

    async def receive(self, timeout_s: float) -> protocol.Message | None:
        """The next message of a used kind, or None when none came within ``timeout_s``."""
        while True:
            if not await self._socket.poll(max(1, int(timeout_s * 1000))):
                return None
            frames = await self._socket.recv_multipart()
            try:
                message = protocol.decode(frames)
            except protocol.ProtocolError as error:
                self.bad_messages += 1
                log.warning("ignored a malformed stream message: %s", error)
                continue
            self.gaps.observe(message.topic, message.seq)
            if message.kind in KINDS:
                return message

    def close(self) -> None:
        """Close the socket (and the context if this reader made it)."""
        self._socket.close(linger=0)
        if self._own_context:
            self._context.term()
