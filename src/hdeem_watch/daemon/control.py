"""The daemon's control socket: ROUTER request handling that answers everything and never crashes.

Each request is one frame after the routing envelope (a REQ client's ``[identity, b"", body]``, a
DEALER's ``[identity, body]`` or ``[identity, b"", body]``); the reply goes back with the same
envelope. Requests are parsed by :func:`hdeem_watch.daemon.protocol.decode_request`; an oversized,
malformed or unknown request gets an error reply, and an exception inside a handler becomes an
``internal`` error reply (logged), never a dead daemon.

A handler is ``handler(args) -> result``; a handler that cannot answer at once (``run.stop`` waits
for the end of the window and the refit, ``baseline.measure`` for its idle window) returns a
:class:`Pending`, which the daemon completes later with :meth:`ControlServer.complete`.

Example:
    >>> handlers = {"ping": lambda args: {"pong": True}}
    >>> reply = dispatch(b'{"id": 1, "op": "ping"}', handlers)
    >>> reply
    b'{"id":1,"ok":true,"result":{"pong":true}}'
    >>> dispatch(b'{"id": 2, "op": "nope"}', handlers)[:60]
    b'{"id":2,"ok":false,"error":{"code":"unknown-op","message":"u'
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import zmq

from hdeem_watch.daemon import protocol
from hdeem_watch.daemon.endpoints import bind, is_loopback
from hdeem_watch.errors import InputError

log = logging.getLogger(__name__)

Handler = Callable[[dict[str, Any]], Any]


@dataclass
class Pending:
    """A reply to be sent later. ``envelope`` and ``request_id`` are filled in by the server.

    Attributes:
        op: the operation it answers.
        context: whatever the handler needs to complete it later.
    """

    op: str
    context: dict[str, Any] = field(default_factory=dict)
    envelope: list[bytes] = field(default_factory=list)
    request_id: Any = None


class OpError(Exception):
    """Raised by a handler for an error reply with a given code (``bad-args``, ``not-found``, ...)."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code


def encode_result(request_id: Any, result: Any, op: str) -> bytes:
    """The success reply of ``result``; an ``internal`` error reply when it cannot be encoded.

    A result that cannot be encoded (a value JSON has no form for, nesting too deep for the
    encoder) must never cost the client its reply: it gets an error naming the operation instead.
    """
    try:
        return protocol.encode_reply_ok(request_id, result)
    except (ValueError, TypeError, RecursionError) as error:
        log.error("the reply of %s cannot be encoded: %s: %s", op, type(error).__name__, error)
        return protocol.encode_reply_error(request_id, "internal",
                                           f"the reply of {op} cannot be encoded ({type(error).__name__})")


def dispatch(data: bytes, handlers: Mapping[str, Handler], max_bytes: int = protocol.MAX_REQUEST_BYTES) -> bytes | Pending:
    """Answer one request frame: the reply frame, or a :class:`Pending` from the handler.

    Never raises: whatever goes wrong becomes an error reply.
    """
    try:
        return _dispatch(data, handlers, max_bytes)
    except Exception as error:  # a bug in the error path itself: still an answer
        log.exception("control request failed")
        return protocol.encode_reply_error(None, "internal", f"{type(error).__name__}")


def _dispatch(data: bytes, handlers: Mapping[str, Handler], max_bytes: int) -> bytes | Pending:
    try:
        request = protocol.decode_request(data, max_bytes=max_bytes)
    except protocol.ProtocolError as error:
        return protocol.encode_reply_error(protocol.request_id_of(data), error.code, str(error))
    handler = handlers.get(request.op)
    if handler is None:
        known = ", ".join(sorted(handlers))
        return protocol.encode_reply_error(request.id, "unknown-op", f"unknown op {request.op[:80]!r}; expected one of {known}")
    try:
        result = handler(request.args)
        if isinstance(result, Pending):
            result.request_id = request.id
            return result
        return encode_result(request.id, result, request.op)
    except OpError as error:
        return protocol.encode_reply_error(request.id, error.code, str(error))
    except protocol.ProtocolError as error:
        return protocol.encode_reply_error(request.id, error.code, str(error))
    except InputError as error:
        return protocol.encode_reply_error(request.id, "bad-args", str(error))
    except Exception as error:  # RecursionError included
        log.exception("control op %s failed", request.op)
        return protocol.encode_reply_error(request.id, "internal", f"{type(error).__name__}: {error}"[:500])


class ControlServer:
    """The ROUTER socket and its request loop step.

    Args:
        context: ZeroMQ context.
        endpoint: where to bind.
        handlers: op name → handler.
        max_bytes: the request size limit.
        secure: applied to the socket before it binds (CURVE).

    Attributes:
        requests: requests received; errors: error replies sent.
    """

    def __init__(self, context: zmq.Context[Any], endpoint: str, handlers: Mapping[str, Handler],
                 max_bytes: int = protocol.MAX_REQUEST_BYTES,
                 secure: Callable[[zmq.Socket[Any]], None] | None = None) -> None:
        self.socket = context.socket(zmq.ROUTER)
        if secure is not None:
            secure(self.socket)
        elif not is_loopback(endpoint):
            log.warning("control %s: TCP without CURVE on a non-loopback address: anyone who can reach it may "
                        "start and stop runs and reset the calibration (allowed by allow_insecure_tcp)", endpoint)
        self.socket.setsockopt(zmq.LINGER, 0)
        # Frames far beyond the limit are not even read into memory: the peer is disconnected.
        self.socket.setsockopt(zmq.MAXMSGSIZE, 64 * max_bytes)
        self.socket.setsockopt(zmq.SNDHWM, 10_000)
        binding = bind(self.socket, endpoint)
        self.endpoint, self._ipc = binding.endpoint, binding.ipc
        self.handlers = dict(handlers)
        self.max_bytes = max_bytes
        self.requests = 0
        self.errors = 0

    def handle(self, max_messages: int = 200) -> list[Pending]:
        """Answer up to ``max_messages`` waiting requests; return the ones answered later."""
        pending: list[Pending] = []
        for _ in range(max_messages):
            try:
                frames = self.socket.recv_multipart(flags=zmq.NOBLOCK)
            except zmq.Again:
                break
            if len(frames) < 2:
                continue  # no routing identity: nothing to reply to
            self.requests += 1
            envelope, body = frames[:-1], frames[-1]
            answer = dispatch(body, self.handlers, self.max_bytes)
            if isinstance(answer, Pending):
                answer.envelope = envelope
                pending.append(answer)
            else:
                if b'"ok":false' in answer[:64]:
                    self.errors += 1
                self._send(envelope, answer)
        return pending

    def complete(self, pending: Pending, result: Any = None, *, error: tuple[str, str] | None = None) -> None:
        """Send the reply of a :class:`Pending` (``error = (code, message)`` for an error reply)."""
        if error is not None:
            self.errors += 1
            self._send(pending.envelope, protocol.encode_reply_error(pending.request_id, error[0], error[1]))
        else:
            self._send(pending.envelope, encode_result(pending.request_id, result, pending.op))

    def _send(self, envelope: list[bytes], body: bytes) -> None:
        try:
            self.socket.send_multipart([*envelope, body], flags=zmq.NOBLOCK)
        except zmq.ZMQError as error:  # peer gone or queue full: the client times out and retries
            log.debug("control reply dropped: %s", error)

    def close(self) -> None:
        """Close the socket and remove its ipc file if it is still the one this server created."""
        self.socket.close(linger=0)
        if self._ipc is not None:
            self._ipc.unlink_if_ours()
