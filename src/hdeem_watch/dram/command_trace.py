"""DRAMPower command traces (CSV): a fast vectorised reader.

The trace -> CommandStats step (DRAMPower's state machine) is :func:`hdeem_watch.dram.trace_state.trace_stats`.

Format (DRAMPower v6 CLI, no header), one command per line::

    cycle,CMD,rank,bankgroup,bank,row,column[,hexdata]

``CMD`` is one of ACT PRE PREA REFA RD RDA WR WRA PDEA PDXA PDEP PDXP SREFEN SREFEX END (and NOP,
ignored), and for DDR5 also PRESB and REFSB; ``bank`` is the flat bank index within the rank; ``cycle`` must not decrease; the END
cycle (else the last cycle) is the evaluation time T. Spaces, tabs and carriage returns are ignored
(DRAMPower trims them). The data field is optional and not used by the core model.

The whole file is parsed with numpy on its raw bytes, in 16 MB chunks of whole lines read into one
reused buffer (no Python code per line): delimiter positions come from one ``flatnonzero``, the
seven field boundaries of every line form a ``reshape`` of them, integer fields are decoded eight
digits at a time with SWAR arithmetic on unaligned 64-bit words, command names are packed into
integers and looked up with ``searchsorted``. Every malformed line raises a one-line
:class:`~hdeem_watch.errors.InputError` with its line number.

Example:
    >>> import tempfile, pathlib
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "t.csv"
    >>> _ = path.write_text("0,ACT,0,0,3,100,0\\n15,RD,0,0,3,100,0\\n40,PRE,0,0,3,100,0\\n100,END,0,0,0,0,0\\n")
    >>> trace = read_command_trace(path)
    >>> [COMMANDS[code] for code in trace.cmd], trace.end_cycle
    (['ACT', 'RD', 'PRE', 'END'], 100)
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from io import FileIO
from pathlib import Path
from typing import NoReturn

import numpy as np

from hdeem_watch.dram.memspec import MemSpec
from hdeem_watch.errors import InputError, excerpt, not_a_file_error

#: Command names in code order (``CommandTrace.cmd`` holds the index into this tuple).
COMMANDS: tuple[str, ...] = ("ACT", "PRE", "PREA", "REFA", "RD", "RDA", "WR", "WRA",
                             "PDEA", "PDXA", "PDEP", "PDXP", "SREFEN", "SREFEX", "END", "NOP",
                             "PRESB", "REFSB")
CODE = {name: i for i, name in enumerate(COMMANDS)}
#: DRAMPower commands of other standards (named in the error message).
OTHER_STANDARD = ("REFB", "REFP2B", "REFDB", "DSMEN", "DSMEX")
#: Commands only DDR5 has (same-bank precharge and refresh); a DDR4 memspec refuses them.
DDR5_ONLY = ("PRESB", "REFSB")

#: Bytes read per chunk (whole lines are parsed per chunk; bounds the temporary arrays).
CHUNK_BYTES = 1 << 24


def _pack(name: str) -> int:
    return sum(byte << (8 * k) for k, byte in enumerate(name.encode()))


_PACKED = np.array(sorted(_pack(n) for n in COMMANDS), dtype=np.int64)
_PACKED_CODE = np.array([CODE[n] for n in sorted(COMMANDS, key=_pack)], dtype=np.uint8)


@dataclass(frozen=True)
class CommandTrace:
    """A parsed command trace (arrays of equal length, one entry per line; END/NOP included).

    Attributes:
        path: where it was read from.
        cycle: command cycle (int64, non-decreasing).
        cmd: command code (uint8, index into :data:`COMMANDS`).
        rank: rank (uint16).
        bank: flat bank index within the rank (uint16).
        end_cycle: the evaluation time T (END's cycle, else the last command's cycle).
        bankgroup: bank group (uint16; DRAMPower ignores it), None unless read with ``addresses=True``.
        row, column: addresses (uint32), None unless read with ``addresses=True``.
    """

    path: str
    cycle: np.ndarray
    cmd: np.ndarray
    rank: np.ndarray
    bank: np.ndarray
    end_cycle: int
    bankgroup: np.ndarray | None = None
    row: np.ndarray | None = None
    column: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.cycle.size)

    def count(self, name: str) -> int:
        """Number of commands named ``name`` (e.g. "RD")."""
        return int(np.count_nonzero(self.cmd == CODE[name]))


#: Bytes of ``"0"`` in front of every chunk, so 16-byte windows before any field stay in the buffer.
_PAD = b"0" * 16
_ZEROS = np.uint64(0x3030303030303030)
_HIGH_BYTES = np.array([((1 << (8 * n)) - 1) << (8 * (8 - n)) for n in range(9)], dtype=np.uint64)
_LOW_BYTES = np.array([(1 << (8 * n)) - 1 for n in range(9)], dtype=np.uint64)


def _words(buf: np.ndarray) -> np.ndarray:
    """The little-endian 8-byte word starting at every byte offset of ``buf`` (a strided view)."""
    return np.ndarray(shape=(buf.size - 7,), dtype="<u8", buffer=buf, strides=(1,))


def _eight_digits(word: np.ndarray, length: np.ndarray, values: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Value and validity of the last ``length`` (0..8) bytes of each word as decimal digits.

    SWAR ("SIMD within a register"): the bytes before the field are replaced by "0", every byte is
    checked to be a digit without carries between bytes, and the eight digits are combined with
    three multiplications (the method of simdjson's ``parse_eight_digits_unrolled``).
    """
    keep = _HIGH_BYTES[length]
    word = (word & keep) | (_ZEROS & ~keep)
    ok = ((word & np.uint64(0xF0F0F0F0F0F0F0F0))
          | (((word + np.uint64(0x0606060606060606)) & np.uint64(0xF0F0F0F0F0F0F0F0)) >> np.uint64(4))
          ) == np.uint64(0x3333333333333333)
    if not values:
        return word, ok
    word = word - _ZEROS
    word = word * np.uint64(10) + (word >> np.uint64(8))
    word = ((word & np.uint64(0x000000FF000000FF)) * np.uint64(100 + (1000000 << 32))
            + ((word >> np.uint64(16)) & np.uint64(0x000000FF000000FF)) * np.uint64(1 + (10000 << 32))
            ) >> np.uint64(32)
    return word, ok


def _parse_uint(buf: np.ndarray, start: np.ndarray, end: np.ndarray,
                values: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Decimal integers in ``buf[start:end]`` per line (up to 16 digits); returns (values, ok).

    Values are uint8 when every field has at most two digits, else int64.

    ``buf`` must begin with :data:`_PAD`. The 8 bytes ending at each field's end are read as one
    word (and the 8 before them for longer fields), then decoded by :func:`_eight_digits`. With
    ``values=False`` only the validity is computed (the returned values are meaningless).
    """
    length = end - start
    longest = int(length.max(initial=0))
    if longest <= 2:  # ranks, bank groups, banks: one or two bytes, plain uint8 arithmetic
        ok = length >= 1
        last = buf[end - 1] - np.uint8(48)  # non-digits wrap to > 9
        ok &= last <= 9
        if longest == 2:
            first = buf[end - 2] - np.uint8(48)
            two = length == 2
            ok &= (first <= 9) | ~two
            last += first * np.uint8(10) * two
        return last, ok
    ok = (length >= 1) & (length <= 16)
    words = _words(buf)
    low = np.clip(length, 0, 8)
    value, good = _eight_digits(words[end - 8], low, values)
    ok &= good
    if (length > 8).any():
        high, good = _eight_digits(words[end - 16], np.clip(length - 8, 0, 8), values)
        ok &= good
        if values:
            value = value + high * np.uint64(100_000_000)
    return value.astype(np.int64), ok


def _fail(where: str, line: int, message: str) -> NoReturn:
    raise InputError(f"{where}: line {line}: {message}")


def _line_text(buf: np.ndarray, start: int, end: int) -> str:
    return excerpt(bytes(buf[start:min(end, start + 80)]))


def _parse_chunk(buf: np.ndarray, first_line: int, where: str, limits: dict[str, int] | None = None,
                 memory_id: str = "", addresses: bool = True) -> dict[str, np.ndarray]:
    """Parse whole lines (``buf`` = :data:`_PAD` + lines ending with a newline); ``first_line`` is 1-based."""
    delim = np.flatnonzero(buf < 45)  # commas, line ends (and any whitespace), in order
    kind = buf[delim]
    newline = kind == 10
    is_delim = newline | (kind == 44)
    if not is_delim.all():
        if np.isin(kind, (32, 9, 13)).any():  # spaces, tabs, CR: trimmed, as DRAMPower does
            return _parse_chunk(buf[(buf != 32) & (buf != 9) & (buf != 13)], first_line, where, limits, memory_id,
                                addresses)
        delim, newline = delim[is_delim], newline[is_delim]  # other bytes are caught by the field checks
    at_end = np.flatnonzero(newline)  # index in delim of each line end
    ends = delim[at_end]
    starts = np.empty_like(ends)
    starts[:1] = len(_PAD)
    starts[1:] = ends[:-1] + 1
    ncomma = np.diff(at_end, prepend=-1) - 1
    bad = (ncomma < 6) | (ncomma > 7)
    if bad.any():
        i = int(np.argmax(bad))
        if ends[i] == starts[i]:
            _fail(where, first_line + i, "empty line; expected cycle,CMD,rank,bankgroup,bank,row,column[,data]")
        _fail(where, first_line + i, f"{ncomma[i] + 1} fields in {_line_text(buf, starts[i], ends[i])}; "
              "expected cycle,CMD,rank,bankgroup,bank,row,column[,data]")
    # drop the line end of lines with a data field: then every line has exactly 7 delimiters
    # (c0..c5 and the end of the column field) and the table is a free reshape
    if (ncomma == 7).any():
        keep = np.ones(delim.size, dtype=bool)
        keep[at_end[ncomma == 7]] = False
        delim = delim[keep]
    table = delim.reshape(-1, 7).T.copy()  # one row per delimiter: contiguous for what follows
    c = list(table)
    c6 = c[6]
    bounds = [(starts, c[0]), None, (c[1] + 1, c[2]), (c[2] + 1, c[3]), (c[3] + 1, c[4]),
              (c[4] + 1, c[5]), (c[5] + 1, c6)]
    names = ("cycle", "CMD", "rank", "bankgroup", "bank", "row", "column")
    out: dict[str, np.ndarray] = {}
    for name, bound in zip(names, bounds):
        if bound is None:
            continue
        needed = addresses or limits is not None or name in ("cycle", "rank", "bank")
        value, ok = _parse_uint(buf, *bound, values=needed)
        if not ok.all():
            i = int(np.argmin(ok))
            text = _line_text(buf, bound[0][i], bound[1][i])
            _fail(where, first_line + i, f"{name} = {text} is not a non-negative integer of at most 16 digits")
        if needed:
            out[name] = value.astype(np.int64, copy=False) if name == "cycle" else value
    # command names: pack up to 6 bytes into an int64 and look them up
    s, e = c[0] + 1, c[1]
    length = np.clip(e - s, 0, 8)
    packed = (_words(buf)[s] & _LOW_BYTES[length]).astype(np.int64)
    pos = np.minimum(np.searchsorted(_PACKED, packed), _PACKED.size - 1)
    known = (_PACKED[pos] == packed) & (length >= 2) & (length <= 6)
    if not known.all():
        i = int(np.argmin(known))
        raw = bytes(buf[s[i]:e[i]])
        hint = " (a command of another DRAM standard)" if raw.decode("latin-1") in OTHER_STANDARD else ""
        _fail(where, first_line + i, f"unknown command {excerpt(raw)}{hint}; expected one of {', '.join(COMMANDS)}")
    out["cmd"] = _PACKED_CODE[pos]
    for name, dtype in (("rank", np.uint16), ("bankgroup", np.uint16), ("bank", np.uint16),
                        ("row", np.uint32), ("column", np.uint32)):
        if name not in out:
            continue
        limit = limits[name] if limits else int(np.iinfo(dtype).max) + 1
        over = out[name] >= limit
        if over.any():
            i = int(np.argmax(over))
            _fail(where, first_line + i, f"{name} {out[name][i]} out of range" + (
                f"; memspec {memory_id!r} has {limit} ({name} 0..{limit - 1})" if limits else ""))
    return out


def _after_last_newline(store: np.ndarray, lo: int, hi: int) -> int:
    """Index just after the last newline in ``store[lo:hi]`` (``lo`` if there is none)."""
    window = 1 << 16
    while True:
        start = max(lo, hi - window)
        found = np.flatnonzero(store[start:hi] == 10)
        if found.size:
            return start + int(found[-1]) + 1
        if start == lo:
            return lo
        window *= 16


_FIELDS = {"cycle": np.int64, "cmd": np.uint8, "rank": np.uint16, "bank": np.uint16}
_ADDRESS_FIELDS = {"bankgroup": np.uint16, "row": np.uint32, "column": np.uint32}
#: No valid line is shorter than this ("0,RD,0,0,0,0,0" and its line end).
_MIN_LINE_BYTES = 15


def read_command_trace(path: str | Path, spec: MemSpec | None = None, *, addresses: bool = False) -> CommandTrace:
    """Read a DRAMPower CSV command trace.

    Args:
        path: the CSV file.
        spec: if given, ranks, bank groups, banks, rows and columns are range-checked against it
            here (else :func:`trace_stats` checks ranks and banks).
        addresses: also keep the bank group, row and column of every command (they are always
            parsed and validated, but not needed by the energy model).

    Raises:
        InputError: unreadable file, a malformed line, an unknown command, a cycle smaller than
            the previous one, a command after END, or (with ``spec``) an address out of range —
            one line with the line number.
    """
    where = str(path)
    limits = None
    if spec is not None:
        limits = {"rank": spec.nbr_of_ranks, "bankgroup": spec.nbr_of_bankgroups, "bank": spec.nbr_of_banks,
                  "row": spec.nbr_of_rows, "column": spec.nbr_of_columns}
    with _open_trace(path, where) as handle:
        arrays = _parse_file(handle, where, limits, spec.memory_id if spec else "", addresses)
    cmd = arrays["cmd"]
    if not cmd.size:
        raise InputError(f"{where}: empty trace; expected cycle,CMD,rank,bankgroup,bank,row,column lines")
    ends = np.flatnonzero(cmd == CODE["END"])
    if ends.size and ends[0] != cmd.size - 1:
        _fail(where, int(ends[0]) + 2, f"{COMMANDS[cmd[ends[0] + 1]]} after END (line {ends[0] + 1}); "
              "expected END to be the last command")
    return CommandTrace(path=where, end_cycle=int(arrays["cycle"][-1]), **arrays)


def _open_trace(path: str | Path, where: str) -> FileIO:
    """The trace file, unbuffered (read in chunks into one reused array)."""
    if Path(path).is_dir():
        raise not_a_file_error(path, "trace file")
    try:
        return open(path, "rb", buffering=0)
    except FileNotFoundError:
        raise not_a_file_error(path, "trace file") from None
    except OSError as error:
        raise InputError(f"{where}: cannot read trace: {error.strerror or error}") from None


def _parse_file(handle: FileIO, where: str, limits: dict[str, int] | None, memory_id: str,
                addresses: bool) -> dict[str, np.ndarray]:
    """Every line of the open trace, parsed chunk by chunk (:func:`_parse_chunk`), as arrays."""
    size = os.fstat(handle.fileno()).st_size
    handle.seek(max(0, size - 4096))
    tail = handle.read()
    remaining = size - (len(tail) - len(tail.rstrip(b" \t\r\n")))  # trailing blank lines are fine
    handle.seek(0)
    # outputs sized for the most lines the file can hold: pages never written stay unused
    wanted = {**_FIELDS, **(_ADDRESS_FIELDS if addresses else {})}
    out = {name: np.empty(remaining // _MIN_LINE_BYTES + 2, dtype=dtype) for name, dtype in wanted.items()}
    count = 0
    pad = len(_PAD)
    store = np.empty(pad + CHUNK_BYTES + 1, dtype=np.uint8)  # reused for every chunk
    store[:pad] = np.frombuffer(_PAD, dtype=np.uint8)
    view = memoryview(store)  # type: ignore[arg-type]
    carry = 0  # bytes of an incomplete last line kept for the next chunk
    while remaining > 0:
        want = min(CHUNK_BYTES - carry, remaining)
        if want <= 0:
            _fail(where, count + 1, f"line longer than {CHUNK_BYTES} bytes")
        got = handle.readinto(view[pad + carry:pad + carry + want])
        if not got:
            break
        remaining -= got
        end = pad + carry + got
        if remaining <= 0:
            store[end] = 10
            end += 1
        cut = _after_last_newline(store, pad, end)
        if cut > pad:
            chunk = _parse_chunk(store[:cut], count + 1, where, limits, memory_id, addresses=addresses)
            out, count = _append(out, count, chunk, where)
        carry = end - cut
        store[pad:pad + carry] = store[cut:end].copy()
    return {name: values[:count] for name, values in out.items()}


def _append(out: dict[str, np.ndarray], count: int, chunk: dict[str, np.ndarray],
            where: str) -> tuple[dict[str, np.ndarray], int]:
    """``chunk``'s lines after the ``count`` in ``out`` (grown if needed); a cycle smaller than the
    one before it is an error naming its line."""
    n = chunk["cmd"].size
    cycle = chunk["cycle"]
    back = np.flatnonzero(np.diff(cycle) < 0)
    if count and cycle[0] < out["cycle"][count - 1]:
        back = np.array([-1])
    if back.size:
        i = int(back[0]) + 1
        before = cycle[i - 1] if i else out["cycle"][count - 1]
        _fail(where, count + i + 1, f"cycle {cycle[i]} is before the previous command's cycle "
              f"{before}; expected non-decreasing cycles")
    if count + n > out["cmd"].size:  # only if a line were shorter than _MIN_LINE_BYTES
        out = {k: np.resize(v, 2 * (count + n)) for k, v in out.items()}
    for name in out:
        out[name][count:count + n] = chunk[name]
    return out, count + n


def check_ranges(spec: MemSpec, trace: CommandTrace, *, full: bool = False) -> None:
    """Raise an InputError (with the line number) for a rank or bank beyond the memspec.

    Args:
        full: also check bank groups, rows and columns (when the trace kept them).
    """
    limits: list[tuple[str, np.ndarray | None, int]] = [
        ("rank", trace.rank, spec.nbr_of_ranks), ("bank", trace.bank, spec.nbr_of_banks)]
    if full:
        limits += [("bankgroup", trace.bankgroup, spec.nbr_of_bankgroups), ("row", trace.row, spec.nbr_of_rows),
                   ("column", trace.column, spec.nbr_of_columns)]
    for name, values, limit in limits:
        if values is None:
            continue
        over = values >= limit
        if over.any():
            i = int(np.argmax(over))
            _fail(trace.path, i + 1, f"{name} {values[i]} out of range; memspec {spec.memory_id!r} has "
                  f"{limit} ({name} 0..{limit - 1})")
