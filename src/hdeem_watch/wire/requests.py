"""Control requests and replies of wire protocol v1 (ROUTER socket; a REQ or DEALER client).

A request is one JSON frame ``{"id": ..., "op": "...", "args": {...}}``; a reply
``{"id": ..., "ok": true, "result": ...}`` or ``{"id": ..., "ok": false, "error": {"code", "message"}}``.
Import these names from :mod:`hdeem_watch.wire.protocol`.

Example:
    >>> decode_request(encode_request("status", {}, 7)).op
    'status'
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from hdeem_watch.wire.json_codec import (
    MAX_JSON_INT,
    MAX_REQUEST_BYTES,
    MAX_REQUEST_DEPTH,
    ProtocolError,
    dumps,
    loads_object,
    quoted,
)


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
    (:data:`~hdeem_watch.wire.json_codec.MAX_REQUEST_DEPTH`); numbers must be finite doubles or
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


#: Longest string ``id`` echoed in the error reply of a request that failed to parse.
MAX_ECHOED_ID_CHARS = 256


def request_id_of(data: bytes) -> Any:
    """Best-effort ``id`` of a request that failed to parse, so that its error reply reaches the
    caller's ``call`` (None when no id can be read within bounds).

    The request is read again leniently: a request refused for a value out of range elsewhere (an
    integer beyond 64 bits, ``1e400``) or for its size still has its ``id`` read, as long as the
    frame is JSON within the nesting bound and no larger than the socket lets in (64 ×
    :data:`MAX_REQUEST_BYTES`). Only an id the protocol allows comes back: a string of at most
    :data:`MAX_ECHOED_ID_CHARS`, a 64-bit integer or a finite number.

    Example:
        >>> request_id_of(b'{"id": 7, "op": "job.start", "args": {"uid": 99999999999999999999}}')
        7
        >>> request_id_of(b'{"id": 99999999999999999999, "op": "ping"}') is None
        True
    """
    if len(data) > 64 * MAX_REQUEST_BYTES:
        return None
    try:
        value = loads_object(data, "request", max_depth=MAX_REQUEST_DEPTH)
    except ProtocolError:
        return None
    return _echoable_id(value.get("id"))


def _echoable_id(rid: Any) -> Any:
    if isinstance(rid, bool):
        return None
    if isinstance(rid, str):
        return rid if len(rid) <= MAX_ECHOED_ID_CHARS and _is_utf8(rid) else None
    if isinstance(rid, int):
        return rid if abs(rid) <= MAX_JSON_INT else None
    if isinstance(rid, float):
        return rid if math.isfinite(rid) else None
    return None


def _is_utf8(text: str) -> bool:
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


@dataclass(frozen=True)
class EncodedResult:
    """A reply's result already encoded (:func:`dumps`): a page many clients ask for is encoded once.

    :func:`encode_reply_ok` puts it in the reply as it is, so the reply's bytes are those of the
    decoded value's reply.

    Example:
        >>> page = EncodedResult.of({"runs": []})
        >>> encode_reply_ok(4, page) == encode_reply_ok(4, {"runs": []})
        True
    """

    json: bytes

    @classmethod
    def of(cls, result: Any) -> EncodedResult:
        """``result`` encoded."""
        return cls(dumps(result))

    def decoded(self) -> Any:
        """The value (as a client reads it)."""
        return json.loads(self.json)


def encode_reply_ok(request_id: Any, result: Any) -> bytes:
    """A success reply frame (an :class:`EncodedResult` goes in as it is)."""
    if isinstance(result, EncodedResult):
        return b'{"id":' + dumps(request_id) + b',"ok":true,"result":' + result.json + b"}"
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


#: A SLURM job id: digits, with an array or het-job suffix (``123_4``, ``123+1``); any short token.
#: A SLURM job id: a 32-bit job number, optionally with an array task (``4242_3``) or a
#: heterogeneous-job component (``4242+1``) suffix (issue 28: ``"abc"`` and 34 digits were taken).
_JOB_ID = re.compile(r"^[0-9]{1,10}(?:[_+][0-9]{1,10})?$")


def job_id_arg(value: Any, key: str = "job_id") -> str:
    """A job id from a request (string or non-negative integer).

    Raises:
        ProtocolError: code ``bad-args``.
    """
    if isinstance(value, int) and not isinstance(value, bool) and value >= 0:
        value = str(value)
    if not isinstance(value, str) or not _JOB_ID.match(value):
        raise ProtocolError(f"args.{key} = {quoted(value)}: expected a SLURM job id such as '4242' or '4242_3'",
                            code="bad-args")
    return value
