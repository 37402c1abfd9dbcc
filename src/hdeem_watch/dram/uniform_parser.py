"""Parse blocks of same-length Ramulator trace lines into preallocated buffers.

Used by the trace readers for traces whose lines all have one length (what the writers and the
kernel streams produce): ``0x<hex> R|W`` (``ramulator``) and ``LD|ST 0x<hex>`` (``ramulator2``).
A block of lines is a strided ``(lines, length + 1)`` byte matrix; every byte is validated and the
hex digits are turned into integers by byte arithmetic (``(c & 15) + 9 × (c >> 6)``, pairs packed
through a ``uint16`` view, read as one big-endian integer). All work arrays are allocated once per
parser: fresh temporaries for every block cost more in page faults (the allocator hands large
freed blocks back to the system) than the arithmetic itself.

Example:
    >>> import numpy as np
    >>> text = np.frombuffer(b"0x40000000 R\\n0x4000ABC0 W\\n", dtype=np.uint8).reshape(2, 13)
    >>> parser = UniformParser(12, "ramulator")
    >>> addresses, writes = np.empty(2, dtype=np.uint64), np.empty(2, dtype=bool)
    >>> parser.parse(text, addresses, writes), [hex(a) for a in addresses], writes.tolist()
    (True, ['0x40000000', '0x4000abc0'], [False, True])
"""

from __future__ import annotations

import mmap

import numpy as np

_EVERY_BYTE_ONE = np.uint64(0x0101010101010101)


def uniform_lines(data: bytes | mmap.mmap) -> np.ndarray | None:
    """The ``(lines, width)`` byte matrix of a trace whose lines all have one length (newline
    included, no CR), as a view of ``data``; ``None`` if the lengths cannot all be equal."""
    width = data.find(b"\n") + 1
    if width <= 1 or len(data) % width or data[width - 2] == 13:
        return None
    buf = np.frombuffer(data, dtype=np.uint8)
    return np.lib.stride_tricks.as_strided(buf, shape=(buf.size // width, width), strides=(width, 1))


def _word(text: bytes) -> int:
    """The little-endian integer of a few bytes (what a word view of them reads)."""
    return int.from_bytes(text, "little")


class UniformParser:
    """A parser for blocks of lines of ``length`` bytes (newline excluded) in format ``fmt``.

    Args:
        length: bytes per line before the newline.
        fmt: ``"ramulator"`` or ``"ramulator2"``.
        block: most lines per call of :meth:`parse`.
    """

    #: Default lines per block.
    BLOCK = 1 << 16

    def __init__(self, length: int, fmt: str, block: int = BLOCK) -> None:
        self.length = length
        self.fmt = fmt
        self.block = block
        first, last = (2, length - 2) if fmt == "ramulator" else (5, length)
        self.digits = (first, last)
        k = last - first
        self.usable = 1 <= k <= 16 and length >= (5 if fmt == "ramulator" else 6)
        width = 8 if k <= 8 else 16
        self.width = width
        shape = (block, width)
        self._padded = np.full(shape, ord("0"), dtype=np.uint8)  # leading columns stay '0'
        self._low = np.empty(shape, dtype=np.uint8)
        self._nibble = np.empty(shape, dtype=np.uint8)
        self._valid = np.empty(shape, dtype=bool)
        self._test = np.empty(shape, dtype=bool)
        self._pairs = np.empty((block, width // 2), dtype=np.uint16)
        self._shifted = np.empty((block, width // 2), dtype=np.uint16)
        self._bytes = np.empty((block, width // 2), dtype=np.uint8)
        self._ok = np.empty(block, dtype=bool)
        self._flag = np.empty(block, dtype=bool)
        self._hex_ok = np.empty(block, dtype=bool)
        self._tail = np.empty(block, dtype=np.uint32)

    def parse(self, rows: np.ndarray, addresses: np.ndarray, writes: np.ndarray) -> bool:
        """Fill ``addresses`` and ``writes`` from ``rows`` (``(lines, length + 1)`` bytes, newline
        last); whether every line was well formed (if not, the outputs are undefined)."""
        c = rows.shape[0]
        if c == 0:
            return True
        if not self.usable or c > self.block or rows.shape[1] != self.length + 1:
            return False
        ok, flag = self._ok[:c], self._flag[:c]
        # fixed bytes through little-endian word views of each line (one strided read per word)
        if self.fmt == "ramulator":  # '0x' ... ' R\n' | ' W\n'
            np.equal(rows[:, 0:2].view("<u2")[:, 0], _word(b"0x"), out=ok)
            tail = self._tail[:c]
            np.bitwise_and(rows[:, self.length - 3:self.length + 1].view("<u4")[:, 0], 0xFFFFFF00, out=tail)
            np.equal(tail, _word(b"\0 W\n"), out=writes)
            np.equal(tail, _word(b"\0 R\n"), out=flag)
        else:  # 'LD 0x' | 'ST 0x' ... '\n'
            head = rows[:, 0:4].view("<u4")[:, 0]
            np.equal(rows[:, 4], ord("x"), out=ok)
            np.equal(rows[:, self.length], 10, out=flag)
            ok &= flag
            np.equal(head, _word(b"ST 0"), out=writes)
            np.equal(head, _word(b"LD 0"), out=flag)
        flag |= writes
        ok &= flag
        first, last = self.digits
        k = last - first
        padded, low, nibble = self._padded[:c], self._low[:c], self._nibble[:c]
        valid, test = self._valid[:c], self._test[:c]
        if last >= self.width:  # the digits' bytes as 8-byte words (one strided read per word)
            np.copyto(padded.view(np.uint64), rows[:, last - self.width:last].view(np.uint64))
            if k < self.width:
                padded[:, :self.width - k] = ord("0")
        else:
            padded[:, self.width - k:] = rows[:, first:last]
        # a-f, A-F (after folding case) or 0-9
        np.bitwise_or(padded, 0x20, out=low)
        low -= np.uint8(ord("a"))
        np.less(low, 6, out=valid)
        np.subtract(padded, np.uint8(ord("0")), out=low)
        np.less(low, 10, out=test)
        valid |= test
        hex_ok = self._hex_ok[:c]
        if self.width == 8:
            np.equal(valid.view(np.uint64)[:, 0], _EVERY_BYTE_ONE, out=hex_ok)
        else:
            words = valid.view(np.uint64)
            np.equal(words[:, 0], _EVERY_BYTE_ONE, out=hex_ok)
            np.equal(words[:, 1], _EVERY_BYTE_ONE, out=flag)
            hex_ok &= flag
        ok &= hex_ok
        # digit values, then pairs of digits packed into bytes
        np.right_shift(padded, 6, out=low)
        low *= np.uint8(9)
        np.bitwise_and(padded, 15, out=nibble)
        low += nibble
        lanes = low.view(np.uint16)  # (first digit, second digit) as low, high byte
        pairs, shifted = self._pairs[:c], self._shifted[:c]
        np.left_shift(lanes, 4, out=pairs)
        np.right_shift(lanes, 8, out=shifted)
        pairs |= shifted
        data = self._bytes[:c]
        np.copyto(data, pairs, casting="unsafe")  # the low byte of each lane
        addresses[:] = data.view(">u8" if self.width == 16 else ">u4")[:, 0]
        return bool(ok.all())

    def parse_range(self, text: np.ndarray, first: int, last: int, addresses: np.ndarray,
                    writes: np.ndarray) -> bool:
        """:meth:`parse` lines ``[first, last)`` of ``text`` block by block into ``addresses`` and
        ``writes`` (both of length ``last − first``); whether every line was well formed."""
        for lo in range(first, last, self.block):
            hi = min(lo + self.block, last)
            if not self.parse(text[lo:hi], addresses[lo - first:hi - first], writes[lo - first:hi - first]):
                return False
        return True
