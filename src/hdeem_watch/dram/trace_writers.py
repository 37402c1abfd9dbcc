"""Memory-request trace writers: Ramulator 1 (``0x<hex> R|W``) and Ramulator 2 (``LD|ST 0x<hex>``).

Vectorised: the hex digits of a million addresses at a time are formatted as a byte matrix
(the reference traces of ``reference/ramulator`` are reproduced byte for byte, see the tests).
The readers are in :mod:`hdeem_watch.dram.request_traces`, which re-exports these functions.

Example:
    >>> import numpy as np
    >>> format_requests(np.array([0x40000000, 0x40000040], dtype=np.uint64), np.array([False, True]))
    b'0x40000000 R\\n0x40000040 W\\n'
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from hdeem_watch.errors import InputError

_HEX_DIGITS = np.frombuffer(b"0123456789abcdef", dtype=np.uint8)
#: (read prefix, write prefix, read suffix, write suffix) per writable format.
_LAYOUT = {
    "ramulator": (b"0x", b"0x", b" R\n", b" W\n"),
    "ramulator2": (b"LD 0x", b"ST 0x", b"\n", b"\n"),
}
_CHUNK = 1 << 20


def _format_chunk(addresses: np.ndarray, is_write: np.ndarray, layout: tuple[bytes, ...]) -> bytes:
    prefix_r, prefix_w, suffix_r, suffix_w = layout
    count = addresses.size
    if count == 0:
        return b""
    raw = addresses.astype(">u8").view(np.uint8).reshape(count, 8)
    nibbles = np.empty((count, 16), dtype=np.uint8)
    nibbles[:, 0::2] = raw >> 4
    nibbles[:, 1::2] = raw & 15
    digits = max(1, (int(addresses.max()).bit_length() + 3) // 4)
    nibbles = nibbles[:, 16 - digits:]
    nonzero = nibbles != 0
    first = np.where(nonzero.any(axis=1), nonzero.argmax(axis=1), digits - 1)
    pre = max(len(prefix_r), len(prefix_w))
    suf = max(len(suffix_r), len(suffix_w))
    out = np.empty((count, pre + digits + suf), dtype=np.uint8)
    keep = np.empty(out.shape, dtype=bool)

    def put(column: int, text_r: bytes, text_w: bytes, width: int) -> None:
        for j in range(width):
            if text_r == text_w:
                out[:, column + j] = text_r[j]
                keep[:, column + j] = True
                continue
            char_r = text_r[j] if j < len(text_r) else 0
            char_w = text_w[j] if j < len(text_w) else 0
            out[:, column + j] = np.where(is_write, char_w, char_r)
            keep[:, column + j] = np.where(is_write, j < len(text_w), j < len(text_r))

    put(0, prefix_r, prefix_w, pre)
    out[:, pre:pre + digits] = _HEX_DIGITS[nibbles]
    keep[:, pre:pre + digits] = np.arange(digits)[None, :] >= first[:, None]
    put(pre + digits, suffix_r, suffix_w, suf)
    return out.tobytes() if keep.all() else out[keep].tobytes()


def iter_formatted(addresses: np.ndarray, is_write: np.ndarray, fmt: str = "ramulator") -> Iterator[bytes]:
    """The trace text of a request stream, in chunks of about a million lines.

    Raises:
        InputError: for a format that cannot be written.
    """
    if fmt not in _LAYOUT:
        raise InputError(f"format {fmt!r}: cannot write it; expected one of {', '.join(_LAYOUT)}")
    addresses = np.asarray(addresses, dtype=np.uint64)
    is_write = np.asarray(is_write, dtype=bool)
    if addresses.shape != is_write.shape:
        raise InputError(f"requests: {addresses.size} addresses but {is_write.size} write flags")
    for start in range(0, addresses.size, _CHUNK):
        stop = start + _CHUNK
        yield _format_chunk(addresses[start:stop], is_write[start:stop], _LAYOUT[fmt])


def format_requests(addresses: np.ndarray, is_write: np.ndarray, fmt: str = "ramulator") -> bytes:
    """The whole trace text of a request stream (see :func:`iter_formatted`)."""
    return b"".join(iter_formatted(addresses, is_write, fmt))


def trace_sha256(addresses: np.ndarray, is_write: np.ndarray, fmt: str = "ramulator") -> str:
    """sha256 (hex) of the trace text, computed chunk by chunk (no whole text in memory)."""
    digest = hashlib.sha256()
    for chunk in iter_formatted(addresses, is_write, fmt):
        digest.update(chunk)
    return digest.hexdigest()


def write_requests(path: str | Path, addresses: np.ndarray, is_write: np.ndarray, fmt: str = "ramulator") -> None:
    """Write a request trace file."""
    with open(path, "wb") as handle:
        for chunk in iter_formatted(addresses, is_write, fmt):
            handle.write(chunk)
