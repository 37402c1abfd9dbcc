"""Shared base of the wire protocol: the error type, error codes, size limit and strict JSON.

Used by :mod:`hdeem_watch.wire.protocol` (stream messages) and
:mod:`hdeem_watch.wire.requests` (control requests); import them from ``protocol``.

Example:
    >>> dumps({"x": float("nan")})
    b'{"x":null}'
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from typing import Any

import numpy as np

#: Largest control request the daemon accepts, in bytes; larger ones get error ``too-large``.
MAX_REQUEST_BYTES = 64 * 1024
#: Deepest nesting of arrays and objects in a control request (``{"args": {...}}`` is depth 2);
#: deeper ones get ``bad-json`` before the parser sees them.
MAX_REQUEST_DEPTH = 32
#: Deepest nesting accepted in any JSON frame (stream headers, replies): far below the depth at
#: which Python's parser or encoder would exhaust the interpreter's stack.
MAX_JSON_DEPTH = 128
#: Largest integer magnitude in a request (a signed 64-bit integer: what SQLite and every
#: client's JSON parser can hold).
MAX_JSON_INT = 2**63 - 1

#: Error codes of control replies.
ERROR_CODES = (
    "bad-json",  # the request frame is not a UTF-8 JSON object
    "bad-request",  # the object lacks "op", or fields have the wrong type
    "too-large",  # larger than MAX_REQUEST_BYTES
    "unknown-op",  # no such operation
    "bad-args",  # arguments missing or invalid for the operation
    "not-found",  # e.g. run.stop with an unknown run_id
    "conflict",  # e.g. run.start while a run is in progress
    "forbidden",  # the peer may not run a state-changing op (daemon/shell/authorization.py says who may)
    "unavailable",  # the operation cannot be served now (e.g. no model for this kernel)
    "internal",  # a bug in the daemon; the message says what
)


#: Most characters of a client's value quoted in an error message or a log line.
MAX_QUOTED_CHARS = 200


def quoted(value: Any, limit: int = MAX_QUOTED_CHARS) -> str:
    """``repr(value)`` cut to ``limit`` characters (saying how long it was), for messages and logs:
    a client's 64 KiB value must not become a 64 KiB log line.

    Example:
        >>> quoted("x" * 1000, 12)
        "'xxxxxxxxxx… (1002 chars)"
    """
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit - 1]}… ({len(text)} chars)"


class ProtocolError(ValueError):
    """A message or request that does not follow protocol v1.

    Attributes:
        code: one of :data:`ERROR_CODES` (used as the control error code).
    """

    def __init__(self, message: str, code: str = "bad-request") -> None:
        super().__init__(message)
        self.code = code


# ----------------------------------------------------------------------------------------------
# JSON with NaN -> null


def jsonable(value: Any) -> Any:
    """``value`` with NaN/inf floats as ``None`` and numpy scalars/arrays as plain Python."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, bool | int | str) or value is None:
        return value
    if isinstance(value, Mapping):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return [jsonable(v) for v in value.tolist()]
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return jsonable(float(value))
    raise ProtocolError(f"cannot encode {type(value).__name__} as JSON")


def dumps(value: Any) -> bytes:
    """Compact UTF-8 JSON, NaN/inf as ``null`` (strict JSON, every parser reads it).

    Plain JSON-ready values (most replies: stored records hold no NaN) go straight to the C
    encoder; only a value it refuses (NaN, a numpy scalar) is rewritten by :func:`jsonable` first.
    """
    try:
        return json.dumps(value, separators=(",", ":"), allow_nan=False).encode()
    except (ValueError, TypeError):
        return json.dumps(jsonable(value), separators=(",", ":"), allow_nan=False).encode()


_STRING_LITERAL = re.compile(r'"[^"\\]*(?:\\.[^"\\]*)*"', re.DOTALL)
_SURROGATE_ESCAPE = re.compile(r"\\u[dD][89a-fA-F]")
_OPENING = np.frombuffer(b"[{", dtype=np.uint8)
_CLOSING = np.frombuffer(b"]}", dtype=np.uint8)


def nesting_depth(text: str) -> int:
    """The deepest nesting of arrays and objects in JSON ``text``, without parsing it.

    Brackets inside string literals do not count; in malformed text (an unterminated string) they
    may, which only overestimates. Linear in the length, no recursion.

    Example:
        >>> nesting_depth('{"a": [1, {"b": "[[["}]}')
        3
    """
    outside = _STRING_LITERAL.sub("", text).encode("utf-8", "surrogatepass")
    if not outside:
        return 0
    codes = np.frombuffer(outside, dtype=np.uint8)
    steps = np.isin(codes, _OPENING).astype(np.int32) - np.isin(codes, _CLOSING).astype(np.int32)
    return int(max(0, np.cumsum(steps).max()))


def _reject_constant(name: str) -> Any:
    raise ProtocolError(f"{name} is not a JSON number (send null for an unknown value)", code="bad-json")


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ProtocolError(f"number {text[:40]} is out of range (finite doubles only)", code="bad-args")
    return value


def _bounded_int(text: str) -> int:
    if len(text.lstrip("-")) > 19 or abs(value := int(text)) > MAX_JSON_INT:
        raise ProtocolError(f"integer {text[:40]} is out of range (|n| < 2**63)", code="bad-args")
    return value


_STRICT = json.JSONDecoder(parse_constant=_reject_constant, parse_float=_finite_float, parse_int=_bounded_int)
_LENIENT = json.JSONDecoder(parse_constant=_reject_constant)


def _check_strings(value: Any, what: str) -> None:
    """Every string (and key) in ``value`` is encodable as UTF-8 (no lone surrogates); iterative."""
    stack = [value]
    while stack:
        item = stack.pop()
        if isinstance(item, str):
            strings: Any = (item,)
        elif isinstance(item, dict):
            strings = item.keys()
            stack.extend(item.values())
        elif isinstance(item, list):
            stack.extend(item)
            continue
        else:
            continue
        for text in strings:
            try:
                text.encode("utf-8")
            except UnicodeEncodeError:
                raise ProtocolError(f"{what}: a string holds a lone UTF-16 surrogate ({text[:40]!a})",
                                    code="bad-args") from None


def loads_object(data: bytes, what: str = "frame", *, max_depth: int = MAX_JSON_DEPTH,
                 strict: bool = False) -> dict[str, Any]:
    """Parse a UTF-8 JSON object within bounds (and, for what a client sent, strictly).

    Always: no ``NaN``/``Infinity`` constants, no lone surrogate in a string, and nesting deeper
    than ``max_depth`` is refused before parsing (a deep body would otherwise exhaust the
    interpreter's stack). ``strict`` (control requests): also no number that overflows a double
    and no integer beyond a signed 64-bit one.

    Raises:
        ProtocolError: code ``bad-json`` when it is not UTF-8 JSON, too deep or not an object;
            ``bad-args`` for a number out of range or a lone surrogate.
    """
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as error:
        raise ProtocolError(f"{what}: not UTF-8 ({error})", code="bad-json") from None
    # Counting brackets is cheap (C); only text with more of them than the bound needs the scan.
    if text.count("[") + text.count("{") > max_depth and (depth := nesting_depth(text)) > max_depth:
        raise ProtocolError(f"{what}: nested {depth} deep; at most {max_depth} levels", code="bad-json")
    try:
        value = (_STRICT if strict else _LENIENT).decode(text)
    except ProtocolError as error:
        raise ProtocolError(f"{what}: {error}", code=error.code) from None
    except (ValueError, RecursionError) as error:
        raise ProtocolError(f"{what}: not JSON ({error})", code="bad-json") from None
    if not isinstance(value, dict):
        raise ProtocolError(f"{what}: expected a JSON object, got {type(value).__name__}", code="bad-json")
    if _SURROGATE_ESCAPE.search(text):  # raw UTF-8 cannot hold a surrogate; only an escape can
        _check_strings(value, what)
    return value
