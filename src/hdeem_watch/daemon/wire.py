"""Shared base of the wire protocol: the error type, error codes, size limit and strict JSON.

Used by :mod:`hdeem_watch.daemon.protocol` (stream messages) and
:mod:`hdeem_watch.daemon.requests` (control requests); import them from ``protocol``.

Example:
    >>> dumps({"x": float("nan")})
    b'{"x":null}'
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

#: Largest control request the daemon accepts, in bytes; larger ones get error ``too-large``.
MAX_REQUEST_BYTES = 64 * 1024

#: Error codes of control replies.
ERROR_CODES = (
    "bad-json",  # the request frame is not a UTF-8 JSON object
    "bad-request",  # the object lacks "op", or fields have the wrong type
    "too-large",  # larger than MAX_REQUEST_BYTES
    "unknown-op",  # no such operation
    "bad-args",  # arguments missing or invalid for the operation
    "not-found",  # e.g. run.stop with an unknown run_id
    "conflict",  # e.g. run.start while a run is in progress
    "unavailable",  # the operation cannot be served now (e.g. no model for this kernel)
    "internal",  # a bug in the daemon; the message says what
)


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
    """Compact UTF-8 JSON, NaN/inf as ``null`` (strict JSON, every parser reads it)."""
    return json.dumps(jsonable(value), separators=(",", ":"), allow_nan=False).encode()


def loads_object(data: bytes, what: str = "frame") -> dict[str, Any]:
    """Parse a UTF-8 JSON object.

    Raises:
        ProtocolError: code ``bad-json`` when it is not UTF-8 JSON or not an object.
    """
    try:
        value = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as error:
        raise ProtocolError(f"{what}: not UTF-8 JSON ({error})", code="bad-json") from None
    if not isinstance(value, dict):
        raise ProtocolError(f"{what}: expected a JSON object, got {type(value).__name__}", code="bad-json")
    return value
