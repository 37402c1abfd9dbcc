"""Control requests and replies of wire protocol v1 (ROUTER socket; a REQ or DEALER client).

A request is one JSON frame ``{"id": ..., "op": "...", "args": {...}}``; a reply
``{"id": ..., "ok": true, "result": ...}`` or ``{"id": ..., "ok": false, "error": {"code", "message"}}``.
Import these names from :mod:`hdeem_watch.daemon.protocol`.

Example:
    >>> decode_request(encode_request("status", {}, 7)).op
    'status'
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from hdeem_watch.daemon.wire import MAX_REQUEST_BYTES, MAX_REQUEST_DEPTH, ProtocolError, dumps, loads_object


@dataclass(frozen=True)
class Request:
    """A parsed control request."""

    id: Any
    op: str
    args: dict[str, Any]


@dataclass(frozen=True)
class Reply:
    """A parsed control reply: ``result`` when ``ok``, else ``code`` and ``message``."""

    id: Any
    ok: bool
    result: Any = None
    code: str = ""
    message: str = ""


def encode_request(op: str, args: Mapping[str, Any] | None = None, request_id: Any = None) -> bytes:
    """One control request frame."""
    return dumps({"id": request_id, "op": op, "args": dict(args or {})})


def decode_request(data: bytes, max_bytes: int = MAX_REQUEST_BYTES) -> Request:
    """Parse a control request frame.

    The body is bounded before it is parsed: size (``max_bytes``), nesting depth
    (:data:`~hdeem_watch.daemon.wire.MAX_REQUEST_DEPTH`); numbers must be finite doubles or
    64-bit integers and strings valid Unicode. Whatever passes can be stored and encoded again.

    Raises:
        ProtocolError: ``too-large``, ``bad-json``, ``bad-request`` or ``bad-args``; its message is
            one line.
    """
    if len(data) > max_bytes:
        raise ProtocolError(f"request of {len(data)} bytes exceeds the limit of {max_bytes}", code="too-large")
    obj = loads_object(data, "request", max_depth=MAX_REQUEST_DEPTH, strict=True)
    op = obj.get("op")
    if not isinstance(op, str) or not op:
        raise ProtocolError(f"request.op = {op!r}: expected a non-empty string")
    args = obj.get("args", {})
    if args is None:
        args = {}
    if not isinstance(args, dict):
        raise ProtocolError(f"request.args: expected an object, got {type(args).__name__}")
    request_id = obj.get("id")
    if not isinstance(request_id, str | int | float | type(None)) or isinstance(request_id, bool):
        raise ProtocolError("request.id: expected a string, a number or null")
    return Request(id=request_id, op=op, args=args)


def request_id_of(data: bytes) -> Any:
    """Best-effort ``id`` of a request that failed to parse (None if it cannot be found)."""
    if len(data) > MAX_REQUEST_BYTES:
        return None
    try:
        value = loads_object(data, "request", max_depth=MAX_REQUEST_DEPTH, strict=True)
    except ProtocolError:
        return None
    rid = value.get("id")
    if isinstance(rid, str | int | float) and not isinstance(rid, bool):
        return rid
    return None


def encode_reply_ok(request_id: Any, result: Any) -> bytes:
    """A success reply frame."""
    return dumps({"id": request_id, "ok": True, "result": result})


def encode_reply_error(request_id: Any, code: str, message: str) -> bytes:
    """An error reply frame (``message`` is flattened to one line)."""
    return dumps({"id": request_id, "ok": False, "error": {"code": code, "message": " ".join(message.split())}})


def decode_reply(data: bytes) -> Reply:
    """Parse a reply frame.

    Raises:
        ProtocolError: when it is not a v1 reply.
    """
    obj = loads_object(data, "reply")
    ok = obj.get("ok")
    if ok is True:
        return Reply(id=obj.get("id"), ok=True, result=obj.get("result"))
    if ok is False:
        error = obj.get("error")
        if not isinstance(error, dict):
            raise ProtocolError("reply.error: expected an object")
        return Reply(
            id=obj.get("id"),
            ok=False,
            code=str(error.get("code", "")),
            message=str(error.get("message", "")),
        )
    raise ProtocolError(f"reply.ok = {ok!r}: expected true or false")
