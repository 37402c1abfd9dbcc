"""Memory-request traces: Ramulator 1/2 writers and readers, Pin and valgrind-lackey readers.

Formats (one request per line, newline-terminated):

- ``ramulator``: Ramulator 1 ``--mode=dram`` traces, ``0x<lowercase hex address> R|W``;
- ``ramulator2``: Ramulator 2 ``LoadStoreTrace``, ``LD|ST 0x<hex address>``;
- ``pinatrace``: Intel Pin's ``pinatrace`` tool, ``0x<ip>: R|W 0x<address>`` (plus its
  ``#``-comment header and the ``#eof`` line); a CPU trace, filtered through a last-level cache;
- ``lackey``: ``valgrind --tool=lackey --trace-mem=yes``, ``I  addr,size`` / `` L addr,size`` /
  `` S addr,size`` / `` M addr,size`` (a modify = load + store), plus ``==pid==`` banner lines;
  a CPU trace, filtered through a last-level cache.

The writers live in :mod:`hdeem_watch.dram.trace_writers` (re-exported here). The Ramulator
readers are vectorised: a trace whose lines all have one length (a generated trace) is
memory-mapped and parsed as a strided byte matrix, block by block, in two halves at once.

Example:
    >>> import numpy as np
    >>> format_requests(np.array([0x40000000, 0x40000040], dtype=np.uint64), np.array([False, True]))
    b'0x40000000 R\\n0x40000040 W\\n'
"""

from __future__ import annotations

import itertools
import mmap
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import numpy as np

from hdeem_watch.dram.pipeline import split_work
from hdeem_watch.dram.progress import ProgressCallback
from hdeem_watch.dram.trace_writers import format_requests, iter_formatted, trace_sha256, write_requests
from hdeem_watch.dram.uniform_parser import UniformParser, uniform_lines
from hdeem_watch.errors import InputError, excerpt, not_a_file_error

__all__ = ["FORMATS", "CacheConfig", "RequestTrace", "cache_filter", "format_requests", "iter_formatted",
           "read_request_trace", "trace_sha256", "write_requests"]

#: The request-trace formats the readers accept.
FORMATS = ("ramulator", "ramulator2", "pinatrace", "lackey")
#: Bytes of lines the CPU-trace readers take per batch (progress is reported once per batch).
BATCH_BYTES = 1 << 20
#: Accesses or lines the cache model handles between two progress reports.
BATCH_LINES = 1 << 16

_Item = TypeVar("_Item")

# ----------------------------------------------------------------------------------------- readers

@dataclass(frozen=True)
class RequestTrace:
    """DRAM requests read from a trace.

    Attributes:
        addresses: physical byte addresses (``uint64``), in order.
        is_write: write flags.
        cpu_accesses: CPU accesses before the cache filter (0 for DRAM-level traces).
    """

    addresses: np.ndarray
    is_write: np.ndarray
    cpu_accesses: int = 0


@dataclass(frozen=True)
class CacheConfig:
    """A last-level cache in front of a CPU trace: set-associative, LRU, write-allocate, write-back.

    Attributes:
        size_bytes: capacity.
        ways: associativity.
        line_bytes: line size (the DRAM request size).
        flush: write back the dirty lines still cached at the end of the trace.
    """

    size_bytes: int = 8 << 20
    ways: int = 16
    line_bytes: int = 64
    flush: bool = False

    def __post_init__(self) -> None:
        sets = self.size_bytes // max(1, self.ways * self.line_bytes)
        if self.ways < 1 or self.line_bytes < 1 or sets < 1 or sets * self.ways * self.line_bytes != self.size_bytes:
            raise InputError(f"cache: {self.size_bytes} bytes, {self.ways} ways, {self.line_bytes}-byte lines "
                             "do not make a whole number of sets")
        if self.line_bytes & (self.line_bytes - 1):
            raise InputError(f"cache: line size {self.line_bytes} is not a power of two")

    @property
    def sets(self) -> int:
        """Number of sets."""
        return self.size_bytes // (self.ways * self.line_bytes)


def cache_filter(line_addresses: np.ndarray, is_write: np.ndarray, cache: CacheConfig, *,
                 progress: ProgressCallback | None = None) -> tuple[np.ndarray, np.ndarray]:
    """DRAM requests caused by CPU accesses to cache lines (line-aligned byte addresses).

    A miss reads the line (a write allocates it too); evicting a dirty line writes it back, right
    after the read that replaced it. Consecutive accesses to one line are merged first (they are
    hits that only set the dirty bit), so the per-access loop runs on the line sequence only.
    ``progress("cache filter", lines_done, lines)`` is called every :data:`BATCH_LINES` lines.
    """
    lines = np.asarray(line_addresses, dtype=np.uint64)
    writes = np.asarray(is_write, dtype=bool)
    if lines.size == 0:
        return np.zeros(0, dtype=np.uint64), np.zeros(0, dtype=bool)
    # merge runs of the same line (vectorised)
    start = np.concatenate(([True], lines[1:] != lines[:-1]))
    run_id = np.cumsum(start) - 1
    run_lines = lines[start]
    run_write = np.zeros(run_lines.size, dtype=bool)
    np.logical_or.at(run_write, run_id, writes)
    line_bytes = np.uint64(cache.line_bytes)
    set_index = ((run_lines // line_bytes) % np.uint64(cache.sets)).astype(np.int64).tolist()
    ways = cache.ways
    sets: dict[int, dict[int, bool]] = {}
    out_addr: list[int] = []
    out_write: list[bool] = []
    for batch in _batches(zip(run_lines.tolist(), run_write.tolist(), set_index), run_lines.size, "cache filter",
                          progress):
        for address, write, index in batch:
            content = sets.get(index)
            if content is None:
                content = sets[index] = {}
            dirty = content.pop(address, None)
            if dirty is None:  # miss: fetch the line, evict the least recently used
                out_addr.append(address)
                out_write.append(False)
                if len(content) >= ways:
                    victim = next(iter(content))
                    if content.pop(victim):
                        out_addr.append(victim)
                        out_write.append(True)
                dirty = False
            content[address] = dirty or write  # most recently used last (dict keeps insertion order)
    if cache.flush:
        for content in sets.values():
            for address, dirty in content.items():
                if dirty:
                    out_addr.append(address)
                    out_write.append(True)
    return np.array(out_addr, dtype=np.uint64), np.array(out_write, dtype=bool)


def _batches(items: Iterable[_Item], total: int, phase: str,
             progress: ProgressCallback | None) -> Iterator[Iterator[_Item]]:
    """``items`` in consecutive slices of :data:`BATCH_LINES` (the caller loops over each), with
    ``progress(phase, done, total)`` after each; one slice of everything without ``progress``."""
    iterator = iter(items)
    if progress is None:
        yield iterator
        return
    for done in range(0, total, BATCH_LINES):
        yield itertools.islice(iterator, BATCH_LINES)
        progress(phase, min(done + BATCH_LINES, total), total)


def _fail(path: str | Path, line: int, text: bytes, expected: str) -> InputError:
    return InputError(f"{path}:{line}: {excerpt(text)} is not a valid request; expected {expected}")


def _lines(data: bytes | mmap.mmap) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    buf = np.frombuffer(data, dtype=np.uint8)
    width = data.find(b"\n") + 1
    if width > 1 and buf.size % width == 0 and data[width - 2] != 13 and (buf[width - 1::width] == 10).all():
        # every line has the same length (a generated trace): no scan of every byte
        starts = np.arange(0, buf.size, width, dtype=np.int64)
        if np.count_nonzero(buf == 10) == starts.size:
            return buf, starts, starts + (width - 1)
    newline = np.flatnonzero(buf == 10)
    ends = newline if (buf.size == 0 or buf[-1] == 10) else np.append(newline, buf.size)
    starts = np.concatenate(([0], ends[:-1] + 1)) if ends.size else np.zeros(0, dtype=np.int64)
    ends = ends - ((ends > starts) & (buf[np.maximum(ends - 1, 0)] == 13))  # tolerate CRLF
    return buf, starts.astype(np.int64), ends.astype(np.int64)


def _parse_same_length(buf: np.ndarray, starts: np.ndarray, length: int, fmt: str) -> tuple[np.ndarray, ...]:
    """Parse lines that all have ``length`` bytes: (values, is_write, ok) per line."""
    count = starts.size
    ok = np.zeros(count, dtype=bool)
    values = np.zeros(count, dtype=np.uint64)
    is_write = np.zeros(count, dtype=bool)
    if length < (5 if fmt == "ramulator" else 6):  # shortest: '0x0 R', 'LD 0x0'
        return values, is_write, ok
    width = length + 1
    if count > 1 and starts[-1] - starts[0] == (count - 1) * width and buf.size >= starts[-1] + width:
        # consecutive lines of one length: a strided view, no gather
        text = np.lib.stride_tricks.as_strided(buf[starts[0]:], shape=(count, length), strides=(width, 1))
    else:
        text = buf[starts[:, None] + np.arange(length)]
    if fmt == "ramulator":
        kind = text[:, -1]
        ok = (text[:, 0] == ord("0")) & (text[:, 1] == ord("x")) & (text[:, -2] == ord(" "))
        ok &= (kind == ord("R")) | (kind == ord("W"))
        digits = text[:, 2:-2]
        is_write = kind == ord("W")
    else:
        head = text[:, 0].astype(np.int32) * 256 + text[:, 1]
        store = ord("S") * 256 + ord("T")
        ok = ((head == ord("L") * 256 + ord("D")) | (head == store)) & (text[:, 2] == ord(" "))
        ok &= (text[:, 3] == ord("0")) & (text[:, 4] == ord("x"))
        digits = text[:, 5:]
        is_write = head == store
    if digits.shape[1] > 16:
        return values, is_write, np.zeros(count, dtype=bool)
    values, hex_ok = _hex_values(digits)
    ok &= hex_ok
    return values, is_write, ok


def _hex_values(digits: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Values of rows of 1..16 ASCII hex digits (a ``(count, k)`` uint8 matrix), and which rows are valid.

    Byte-wide arithmetic instead of a table: a digit's value is ``(c & 15) + 9 × (c >> 6)`` (``0-9``,
    ``a-f``, ``A-F``); pairs of digits are packed into bytes through a ``uint16`` view and the bytes
    read as one big-endian integer.
    """
    count, k = digits.shape
    width = 8 if k <= 8 else 16
    padded = np.full((count, width), ord("0"), dtype=np.uint8)
    padded[:, width - k:] = digits
    low = padded | np.uint8(0x20)  # A-F -> a-f (digits unchanged)
    low -= np.uint8(ord("a"))
    valid = low < np.uint8(6)
    low = padded - np.uint8(ord("0"))
    valid |= low < np.uint8(10)
    ok = valid.view(np.uint64) == np.uint64(0x0101010101010101)
    ok = ok.all(axis=1) if width == 16 else ok[:, 0]
    nibbles = padded >> np.uint8(6)
    nibbles *= np.uint8(9)
    padded &= np.uint8(15)
    nibbles += padded
    lanes = nibbles.view(np.uint16)  # (first digit, second digit) as low, high byte
    packed = lanes << np.uint16(4)
    packed |= lanes >> np.uint16(8)
    data = packed.astype(np.uint8)
    values = data.view(">u8" if width == 16 else ">u4")[:, 0].astype(np.uint64)
    return values, ok


def _read_uniform(text: np.ndarray, fmt: str) -> tuple[np.ndarray, np.ndarray] | None:
    """Parse a trace whose lines all have one length (:func:`uniform_lines`), block by block.

    Large traces are parsed in two halves at once (:func:`hdeem_watch.dram.pipeline.split_work`:
    two threads; numpy releases the GIL in its loops, which are long here). Returns
    ``None`` if any line is malformed (the general path then names it).
    """
    count, width = text.shape

    def parse(first: int, last: int, out: tuple[np.ndarray, ...]) -> bool:
        parser = UniformParser(width - 1, fmt)  # one per half: its own work arrays
        return parser.parse_range(text, first, last, *out)

    if count >= 4 * UniformParser.BLOCK:
        result = split_work(parse, count, (np.uint64, np.bool_))
        return (result[0], result[1]) if result is not None else None
    out = (np.empty(count, dtype=np.uint64), np.empty(count, dtype=bool))
    return out if parse(0, count, out) else None


def map_file(path: str | Path, *, populate: bool = True) -> bytes | mmap.mmap:
    """The file's bytes, memory-mapped (no copy; pre-faulted with ``populate``), or read if it
    cannot be mapped."""
    with open(path, "rb") as handle:
        try:
            flags = mmap.MAP_PRIVATE | (getattr(mmap, "MAP_POPULATE", 0) if populate else 0)
            return mmap.mmap(handle.fileno(), 0, flags=flags, prot=mmap.PROT_READ)
        except (ValueError, OSError, AttributeError):  # empty file, special file, no mmap flags
            return handle.read()


def _read_dram_trace(path: str | Path, fmt: str) -> RequestTrace:
    data = map_file(path)
    text = uniform_lines(data)
    if text is not None:
        # every line may have the same length (a generated trace): parse it as a strided matrix
        uniform = _read_uniform(text, fmt)
        if uniform is not None:
            return RequestTrace(*uniform)
    buf, starts, ends = _lines(data)
    keep = ends > starts  # blank lines are skipped
    line_no = np.flatnonzero(keep) + 1
    starts, ends = starts[keep], ends[keep]
    addresses = np.zeros(starts.size, dtype=np.uint64)
    writes = np.zeros(starts.size, dtype=bool)
    expected = "'0x<hex address> R|W'" if fmt == "ramulator" else "'LD|ST 0x<hex address>'"
    chunk = 1 << 18
    for first in range(0, starts.size, chunk):
        s = starts[first:first + chunk]
        lengths = ends[first:first + chunk] - s
        bad = np.zeros(s.size, dtype=bool)
        # lines of one length form a matrix: parse column by column (few distinct lengths)
        for length in np.flatnonzero(np.bincount(np.minimum(lengths, 64))):
            mine = np.flatnonzero(lengths == length) if length < 64 else np.flatnonzero(lengths >= 64)
            values, is_write, ok = _parse_same_length(buf, s[mine], int(length), fmt)
            addresses[first + mine] = values
            writes[first + mine] = is_write
            bad[mine] = ~ok
        if bad.any():
            index = first + int(np.flatnonzero(bad)[0])
            raise _fail(path, int(line_no[index]), data[starts[index]:ends[index]], expected)
    return RequestTrace(addresses, writes)


def _split_access(address: int, size: int, line_bytes: int) -> range:
    first = address - address % line_bytes
    return range(first, address + max(size, 1), line_bytes)


def _line_batches(path: str | Path, progress: ProgressCallback | None) -> Iterator[tuple[int, list[bytes]]]:
    """``(number of the first line, lines)`` of a text file in batches of about :data:`BATCH_BYTES`,
    with ``progress("reading trace", bytes_read, file_size)`` after each batch."""
    size = Path(path).stat().st_size
    first = 1
    with open(path, "rb") as handle:
        while batch := handle.readlines(BATCH_BYTES):
            yield first, batch
            first += len(batch)
            if progress is not None:
                progress("reading trace", handle.tell(), size)


def _read_pinatrace(path: str | Path, progress: ProgressCallback | None = None) -> tuple[list[int], list[bool], int]:
    addresses: list[int] = []
    writes: list[bool] = []
    count = 0
    for first, batch in _line_batches(path, progress):
        for number, raw in enumerate(batch, first):
            text = raw.strip()
            if not text or text.startswith(b"#"):
                continue
            parts = text.split()
            try:
                if len(parts) != 3 or not parts[0].endswith(b":") or parts[1] not in (b"R", b"W"):
                    raise ValueError
                int(parts[0][:-1], 16)
                address = int(parts[2], 16)
            except ValueError:
                raise _fail(path, number, text, "'0x<ip>: R|W 0x<address>' (Pin pinatrace)") from None
            addresses.append(address)
            writes.append(parts[1] == b"W")
            count += 1
    return addresses, writes, count


def _read_lackey(path: str | Path, instructions: bool,
                 progress: ProgressCallback | None = None) -> tuple[list[int], list[int], list[bool], int]:
    addresses: list[int] = []
    sizes: list[int] = []
    writes: list[bool] = []
    count = 0
    kinds = {b"L": (False,), b"S": (True,), b"M": (False, True), b"I": (False,)}
    for first, batch in _line_batches(path, progress):
        for number, raw in enumerate(batch, first):
            text = raw.rstrip(b"\r\n")
            if not text.strip() or text.startswith(b"=="):
                continue
            parts = text.split()
            try:
                if len(parts) != 2 or parts[0] not in kinds:
                    raise ValueError
                field, _, size = parts[1].partition(b",")
                address, length = int(field, 16), int(size)
            except ValueError:
                raise _fail(path, number, text, "' L|S|M <hex address>,<size>' or 'I  <hex address>,<size>' "
                                                "(valgrind lackey --trace-mem=yes)") from None
            count += 1
            if parts[0] == b"I" and not instructions:
                continue
            for write in kinds[parts[0]]:
                addresses.append(address)
                sizes.append(length)
                writes.append(write)
    return addresses, sizes, writes, count


def read_request_trace(path: str | Path, fmt: str, *, cache: CacheConfig | None = None,
                       instructions: bool = False, progress: ProgressCallback | None = None) -> RequestTrace:
    """Read a request trace.

    Args:
        path: the file.
        fmt: one of :data:`FORMATS`.
        cache: the last-level cache CPU traces (``pinatrace``, ``lackey``) go through
            (default: 8 MiB, 16 ways, 64-byte lines).
        instructions: also feed lackey's instruction fetches (``I`` lines) to the cache.
        progress: told how far reading (bytes), splitting accesses into cache lines and the cache
            filter are, for CPU traces (:mod:`hdeem_watch.dram.progress`); the vectorised
            Ramulator readers take a second per GB and report nothing.

    Raises:
        InputError: ``file:line`` and what was wrong, for a malformed line; or a bad format.
    """
    if fmt not in FORMATS:
        raise InputError(f"--format {fmt!r}: expected one of {', '.join(FORMATS)}")
    if not Path(path).is_file():
        raise not_a_file_error(path, "trace file")
    if fmt in ("ramulator", "ramulator2"):
        return _read_dram_trace(path, fmt)
    cache = cache or CacheConfig()
    if fmt == "pinatrace":
        addresses, writes, count = _read_pinatrace(path, progress)
        sizes = [1] * len(addresses)  # pinatrace records no size
    else:
        addresses, sizes, writes, count = _read_lackey(path, instructions, progress)
    line_addresses: list[int] = []
    line_writes: list[bool] = []
    for batch in _batches(zip(addresses, sizes, writes), len(addresses), "cache lines", progress):
        for address, size, write in batch:
            for line in _split_access(address, size, cache.line_bytes):
                line_addresses.append(line)
                line_writes.append(write)
    dram, dram_writes = cache_filter(np.array(line_addresses, dtype=np.uint64), np.array(line_writes, dtype=bool), cache,
                                     progress=progress)
    return RequestTrace(dram, dram_writes, cpu_accesses=count)
