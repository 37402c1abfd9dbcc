"""The daemon's control socket: ROUTER request handling that answers everything and never crashes.

Each request is one frame after the routing envelope (a REQ client's ``[identity, b"", body]``, a
DEALER's ``[identity, body]`` or ``[identity, b"", body]``); the reply goes back with the same
envelope. Requests are parsed by :func:`hdeem_watch.wire.protocol.decode_request`; an oversized,
malformed or unknown request gets an error reply, and an exception inside a handler becomes an
``internal`` error reply (logged), never a dead daemon.

State-changing operations are authorized per request
(:mod:`hdeem_watch.daemon.shell.authorization`): the peer is read from the frame's libzmq properties
(``Peer-Address`` with the ``SO_PEERCRED`` credentials on ipc, ``User-Id`` from the ZAP handler on
CURVE TCP) only when the op needs it; a refusal is a ``forbidden`` error reply, logged. The server
may listen on several endpoints (one socket each, so each request's transport is known): the local
ipc one and a TCP one for other nodes.

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
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import zmq

from hdeem_watch.daemon.shell.authorization import (
    FORBIDDEN,
    RULE,
    STATE_CHANGING_OPS,
    Authorizer,
    Peer,
    ipc_peer,
    tcp_peer,
)
from hdeem_watch.daemon.shell.endpoints import bind, is_loopback
from hdeem_watch.errors import InputError
from hdeem_watch.wire import protocol

log = logging.getLogger(__name__)

Handler = Callable[[dict[str, Any]], Any]
#: The op that tells a client who the daemon takes it for and whether it may change state.
WHOAMI = "whoami"


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
    socket: Any = None


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


class RequestPeer:
    """The sender of one request, read from its frame only when an op needs it.

    Args:
        frame: the request's body frame (its libzmq properties name the peer).
        transport: ``ipc``, ``tcp`` or ``inproc``.
        authorizer: the policy.
        on_refusal: called with the op and the peer when a request is refused (count and log).
    """

    def __init__(self, frame: zmq.Frame, transport: str, authorizer: Authorizer,
                 on_refusal: Callable[[str, Peer], None] | None = None) -> None:
        self._frame = frame
        self._transport = transport
        self._authorizer = authorizer
        self._on_refusal = on_refusal
        self._peer: Peer | None = None

    @property
    def peer(self) -> Peer:
        """Who sent the request."""
        if self._peer is None:
            self._peer = peer_of(self._frame, self._transport)
        return self._peer

    def refusal(self, op: str) -> str | None:
        """Why the peer may not run ``op``, or None."""
        if op not in STATE_CHANGING_OPS:
            return None
        refusal = self._authorizer.refusal(op, self.peer)
        if refusal is not None and self._on_refusal is not None:
            self._on_refusal(op, self.peer)
        return refusal

    def whoami(self) -> dict[str, Any]:
        """The ``whoami`` result: the peer as the daemon sees it, its role and what it may change
        now (``may_change_state``: it may announce runs; ``allowed_ops``: every state-changing op
        it may run)."""
        peer = self.peer
        may = self._authorizer.may_change_state(peer)
        return {"transport": peer.transport, "uid": peer.uid, "user": peer.user, "pid": peer.pid,
                "peer": peer.describe(), "role": self._authorizer.role(peer), "may_change_state": may,
                "allowed_ops": self._authorizer.allowed_ops(peer),
                "reason": None if may else f"changing state needs {RULE}",
                "state_changing_ops": sorted(STATE_CHANGING_OPS)}


def dispatch(data: bytes, handlers: Mapping[str, Handler], max_bytes: int = protocol.MAX_REQUEST_BYTES,
             *, peer: RequestPeer | None = None) -> bytes | Pending:
    """Answer one request frame: the reply frame, or a :class:`Pending` from the handler.

    With ``peer``, a state-changing op the peer may not run gets a ``forbidden`` reply, and
    ``whoami`` is answered. Never raises: whatever goes wrong becomes an error reply.
    """
    try:
        return _dispatch(data, handlers, max_bytes, peer)
    except Exception as error:  # a bug in the error path itself: still an answer
        log.exception("control request failed")
        return protocol.encode_reply_error(None, "internal", f"{type(error).__name__}")


def _dispatch(data: bytes, handlers: Mapping[str, Handler], max_bytes: int,
              peer: RequestPeer | None) -> bytes | Pending:
    try:
        request = protocol.decode_request(data, max_bytes=max_bytes)
    except protocol.ProtocolError as error:
        return protocol.encode_reply_error(protocol.request_id_of(data), error.code, str(error))
    if request.op == WHOAMI and peer is not None and WHOAMI not in handlers:
        return encode_result(request.id, peer.whoami(), request.op)
    handler = handlers.get(request.op)
    if handler is None:
        known = ", ".join(sorted([*handlers, WHOAMI] if peer is not None else handlers))
        return protocol.encode_reply_error(request.id, "unknown-op", f"unknown op {request.op[:80]!r}; expected one of {known}")
    refusal = peer.refusal(request.op) if peer is not None else None
    if refusal is not None:
        return protocol.encode_reply_error(request.id, FORBIDDEN, refusal)
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
    """The ROUTER sockets (one per endpoint) and their request loop step.

    Args:
        context: ZeroMQ context.
        endpoint: where to bind (the local endpoint; :attr:`socket`).
        handlers: op name → handler.
        max_bytes: the request size limit.
        secure: applied to every TCP socket before it binds (CURVE); ipc sockets are protected by
            their file mode and the peer's kernel credentials instead.
        extra_endpoints: further endpoints served alike (e.g. ``tcp://*:5591`` for other nodes
            beside the local ipc socket).
        authorizer: who may run the state-changing ops (None: everybody who reaches a socket).

    Attributes:
        requests: requests received; errors: error replies sent; refused: requests refused.
    """

    def __init__(self, context: zmq.Context[Any], endpoint: str, handlers: Mapping[str, Handler],
                 max_bytes: int = protocol.MAX_REQUEST_BYTES,
                 secure: Callable[[zmq.Socket[Any]], None] | None = None, *,
                 extra_endpoints: tuple[str, ...] = (), authorizer: Authorizer | None = None) -> None:
        self._bound: list[tuple[zmq.Socket[Any], str, Any]] = []
        try:
            for each in (endpoint, *extra_endpoints):
                self._bind(context, each, max_bytes, secure)
        except BaseException:
            self.close()
            raise
        self.socket = self._bound[0][0]
        self.sockets = [sock for sock, _transport, _ipc in self._bound]
        self.endpoint = self.endpoints[0]
        self.handlers = dict(handlers)
        self.max_bytes = max_bytes
        self.authorizer = authorizer
        self.requests = 0
        self.errors = 0
        self.refused = 0

    def _bind(self, context: zmq.Context[Any], endpoint: str, max_bytes: int,
              secure: Callable[[zmq.Socket[Any]], None] | None) -> None:
        sock = context.socket(zmq.ROUTER)
        transport = endpoint.split("://", 1)[0]
        try:
            if secure is not None and transport == "tcp":
                secure(sock)
            elif not is_loopback(endpoint):
                log.warning("control %s: TCP without CURVE on a non-loopback address: anyone who can reach it may "
                            "read the node; nobody there can be identified to change its state (allowed by "
                            "allow_insecure_tcp)", endpoint)
            sock.setsockopt(zmq.LINGER, 0)
            # Frames far beyond the limit are not even read into memory: the peer is disconnected.
            sock.setsockopt(zmq.MAXMSGSIZE, 64 * max_bytes)
            sock.setsockopt(zmq.SNDHWM, 10_000)
            binding = bind(sock, endpoint)
        except BaseException:
            sock.close(linger=0)
            raise
        self._bound.append((sock, transport, binding))

    @property
    def endpoints(self) -> list[str]:
        """The bound endpoints (the local one first)."""
        return [binding.endpoint for _sock, _transport, binding in self._bound]

    def waiting(self) -> bool:
        """Whether a request waits on any socket."""
        return any(int(sock.getsockopt(zmq.EVENTS)) & zmq.POLLIN for sock in self.sockets)

    def handle(self, max_messages: int = 200) -> list[Pending]:
        """Answer up to ``max_messages`` waiting requests per socket; return the ones answered later."""
        pending: list[Pending] = []
        for sock, transport, _binding in self._bound:
            for _ in range(max_messages):
                try:
                    frames = sock.recv_multipart(flags=zmq.NOBLOCK, copy=False)
                except zmq.Again:
                    break
                if len(frames) < 2:
                    continue  # no routing identity: nothing to reply to
                self.requests += 1
                envelope, body = [f.bytes for f in frames[:-1]], frames[-1]
                peer = None if self.authorizer is None else RequestPeer(body, transport, self.authorizer,
                                                                         self._refused)
                answer = dispatch(body.bytes, self.handlers, self.max_bytes, peer=peer)
                if isinstance(answer, Pending):
                    answer.envelope = envelope
                    answer.socket = sock
                    pending.append(answer)
                else:
                    if b'"ok":false' in answer[:64]:
                        self.errors += 1
                    self._send(sock, envelope, answer)
        return pending

    def _refused(self, op: str, peer: Peer) -> None:
        self.refused += 1
        log.warning("control: refused %s from %s", op, peer.describe())

    def complete(self, pending: Pending, result: Any = None, *, error: tuple[str, str] | None = None) -> None:
        """Send the reply of a :class:`Pending` (``error = (code, message)`` for an error reply)."""
        sock = pending.socket if pending.socket is not None else self.socket
        if error is not None:
            self.errors += 1
            self._send(sock, pending.envelope, protocol.encode_reply_error(pending.request_id, error[0], error[1]))
        else:
            self._send(sock, pending.envelope, encode_result(pending.request_id, result, pending.op))

    @staticmethod
    def _send(sock: zmq.Socket[Any], envelope: list[bytes], body: bytes) -> None:
        try:
            sock.send_multipart([*envelope, body], flags=zmq.NOBLOCK)
        except zmq.ZMQError as error:  # peer gone or queue full: the client times out and retries
            log.debug("control reply dropped: %s", error)

    def close(self) -> None:
        """Close the sockets and remove each ipc file if it is still the one this server created."""
        for sock, _transport, binding in self._bound:
            sock.close(linger=0)
            if binding.ipc is not None:
                binding.ipc.unlink_if_ours()
        self._bound = []


def peer_of(frame: zmq.Frame, transport: str) -> Peer:
    """Who sent ``frame``: libzmq's ``Peer-Address`` (ipc: with ``SO_PEERCRED``'s ``:uid:gid:pid``) and,
    on TCP, the ``User-Id`` the ZAP handler gave the client's CURVE key."""
    address = _property(frame, "Peer-Address") or ""
    if transport == "ipc":
        return ipc_peer(address)
    if transport == "tcp":
        return tcp_peer(address, _property(frame, "User-Id"))
    if transport == "inproc":  # a socket inside the daemon's own process
        return Peer("inproc", uid=os.geteuid())
    return Peer(transport, address=address)


def _property(frame: zmq.Frame, name: str) -> str | None:
    try:
        value = frame.get(name)
    except zmq.ZMQError:  # the connection has no such property (no ZAP handler, not a socket file)
        return None
    return value if isinstance(value, str) else None
