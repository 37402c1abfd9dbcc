"""DRAMPower command traces (CSV): a fast vectorised reader and the trace -> CommandStats step.

Format (DRAMPower v6 CLI, no header), one command per line::

    cycle,CMD,rank,bankgroup,bank,row,column[,hexdata]

``CMD`` is one of ACT PRE PREA REFA RD RDA WR WRA PDEA PDXA PDEP PDXP SREFEN SREFEX END (and NOP,
ignored); ``bank`` is the flat bank index within the rank; ``cycle`` must not decrease; the END
cycle (else the last cycle) is the evaluation time T. Spaces, tabs and carriage returns are ignored
(DRAMPower trims them). The data field is optional and not used by the core model.

The whole file is parsed with numpy on its raw bytes, in chunks of whole lines (no Python code per
line): delimiter positions come from ``flatnonzero``, integer fields are accumulated digit by digit
over all lines at once, command names are packed into integers and looked up with
``searchsorted``. Every malformed line raises a one-line :class:`~hdeem_watch.errors.InputError`
with its line number.

Example:
    >>> import tempfile, pathlib
    >>> from hdeem_watch.dram.memspec import preset
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "t.csv"
    >>> _ = path.write_text("0,ACT,0,0,3,100,0\\n15,RD,0,0,3,100,0\\n40,PRE,0,0,3,100,0\\n100,END,0,0,0,0,0\\n")
    >>> trace = read_command_trace(path)
    >>> stats = trace_stats(preset("ddr4-2133-x8-4gb"), trace)
    >>> stats.ranks[0].act, stats.ranks[0].rd, stats.ranks[0].cycles_act, stats.ranks[0].cycles_pre
    (1.0, 1.0, 40.0, 60.0)
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import NoReturn

import numpy as np

from hdeem_watch.dram.memspec import MemSpec
from hdeem_watch.dram.stats import CommandStats
from hdeem_watch.errors import InputError

#: Command names in code order (``CommandTrace.cmd`` holds the index into this tuple).
COMMANDS: tuple[str, ...] = ("ACT", "PRE", "PREA", "REFA", "RD", "RDA", "WR", "WRA",
                             "PDEA", "PDXA", "PDEP", "PDXP", "SREFEN", "SREFEX", "END", "NOP")
CODE = {name: i for i, name in enumerate(COMMANDS)}
#: DRAMPower commands of other standards (named in the error message).
OTHER_STANDARD = ("PRESB", "REFB", "REFSB", "REFP2B", "REFDB", "DSMEN", "DSMEX")

#: Bytes read per chunk (whole lines are parsed per chunk; bounds the temporary arrays).
CHUNK_BYTES = 1 << 24
_MAX_DIGITS = 18


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
        bankgroup: bank group (uint16; informational, DRAMPower ignores it).
        bank: flat bank index within the rank (uint16).
        row, column: addresses (uint32; informational).
        end_cycle: the evaluation time T (END's cycle, else the last command's cycle).
    """

    path: str
    cycle: np.ndarray
    cmd: np.ndarray
    rank: np.ndarray
    bankgroup: np.ndarray
    bank: np.ndarray
    row: np.ndarray
    column: np.ndarray
    end_cycle: int

    def __len__(self) -> int:
        return int(self.cycle.size)

    def count(self, name: str) -> int:
        """Number of commands named ``name`` (e.g. "RD")."""
        return int(np.count_nonzero(self.cmd == CODE[name]))


def _parse_uint(buf: np.ndarray, start: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Decimal integers in ``buf[start:end]`` per line; returns (values int64, ok mask)."""
    length = end - start
    ok = (length >= 1) & (length <= _MAX_DIGITS)
    value = np.zeros(start.size, dtype=np.int64)
    last = buf.size - 1
    for k in range(int(length.max(initial=0)) if start.size else 0):
        inside = k < length
        digit = buf[np.minimum(start + k, last)].astype(np.int64) - 48
        ok &= ~inside | ((digit >= 0) & (digit <= 9))
        value = np.where(inside, value * 10 + digit, value)
    return value, ok


def _fail(where: str, line: int, message: str) -> NoReturn:
    raise InputError(f"{where}: line {line}: {message}")


def _line_text(buf: np.ndarray, start: int, end: int) -> str:
    return bytes(buf[start:min(end, start + 80)]).decode("ascii", "replace")


def _parse_chunk(buf: np.ndarray, first_line: int, where: str) -> dict[str, np.ndarray]:
    """Parse whole lines (``buf`` ends with a newline); ``first_line`` is the 1-based line number."""
    ends = np.flatnonzero(buf == 10)
    starts = np.empty_like(ends)
    starts[:1] = 0
    starts[1:] = ends[:-1] + 1
    commas = np.flatnonzero(buf == 44)
    upto = np.searchsorted(commas, ends)  # commas before each line end
    ncomma = np.diff(upto, prepend=0)
    bad = (ncomma < 6) | (ncomma > 7)
    if bad.any():
        i = int(np.argmax(bad))
        if ends[i] == starts[i]:
            _fail(where, first_line + i, "empty line; expected cycle,CMD,rank,bankgroup,bank,row,column[,data]")
        _fail(where, first_line + i, f"{ncomma[i] + 1} fields in {_line_text(buf, starts[i], ends[i])!r}; "
              "expected cycle,CMD,rank,bankgroup,bank,row,column[,data]")
    first = upto - ncomma
    c = [commas[first + j] for j in range(6)]
    has_data = ncomma == 7
    c6 = np.where(has_data, commas[np.minimum(first + 6, commas.size - 1)], ends)
    bounds = [(starts, c[0]), None, (c[1] + 1, c[2]), (c[2] + 1, c[3]), (c[3] + 1, c[4]),
              (c[4] + 1, c[5]), (c[5] + 1, c6)]
    names = ("cycle", "CMD", "rank", "bankgroup", "bank", "row", "column")
    out: dict[str, np.ndarray] = {}
    for name, bound in zip(names, bounds):
        if bound is None:
            continue
        value, ok = _parse_uint(buf, *bound)
        if not ok.all():
            i = int(np.argmin(ok))
            text = bytes(buf[bound[0][i]:bound[1][i]]).decode("ascii", "replace")
            _fail(where, first_line + i, f"{name} = {text!r} is not a non-negative integer")
        out[name] = value
    # command names: pack up to 6 bytes into an int64 and look them up
    s, e = c[0] + 1, c[1]
    length = e - s
    packed = np.zeros(s.size, dtype=np.int64)
    last = buf.size - 1
    for k in range(6):
        packed |= np.where(k < length, buf[np.minimum(s + k, last)].astype(np.int64) << (8 * k), 0)
    pos = np.minimum(np.searchsorted(_PACKED, packed), _PACKED.size - 1)
    known = (_PACKED[pos] == packed) & (length >= 2) & (length <= 6)
    if not known.all():
        i = int(np.argmin(known))
        text = bytes(buf[s[i]:e[i]]).decode("ascii", "replace")
        hint = " (a command of another DRAM standard)" if text in OTHER_STANDARD else ""
        _fail(where, first_line + i, f"unknown command {text!r}{hint}; expected one of {', '.join(COMMANDS)}")
    out["cmd"] = _PACKED_CODE[pos]
    return out


def read_command_trace(path: str | Path, spec: MemSpec | None = None) -> CommandTrace:
    """Read a DRAMPower CSV command trace.

    Args:
        path: the CSV file.
        spec: if given, ranks, bank groups, banks, rows and columns are range-checked against it
            here (else :func:`trace_stats` checks ranks and banks).

    Raises:
        InputError: unreadable file, a malformed line, an unknown command, a cycle smaller than
            the previous one, a command after END, or (with ``spec``) an address out of range —
            one line with the line number.
    """
    where = str(path)
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("cycle", "cmd", "rank", "bankgroup", "bank", "row", "column")}
    line = 1
    try:
        handle = open(path, "rb")  # noqa: SIM115 (closed by the with below)
    except OSError as error:
        raise InputError(f"{where}: cannot read trace: {error.strerror or error}") from None
    with handle:
        size = os.fstat(handle.fileno()).st_size
        handle.seek(max(0, size - 4096))
        tail = handle.read()
        remaining = size - (len(tail) - len(tail.rstrip(b" \t\r\n")))  # trailing blank lines are fine
        handle.seek(0)
        carry = b""
        while remaining > 0:
            block = handle.read(min(CHUNK_BYTES, remaining))
            if not block:
                break
            remaining -= len(block)
            data = carry + block
            if remaining <= 0:
                data += b"\n"
            cut = data.rfind(b"\n") + 1
            carry = data[cut:]
            if cut == 0:
                continue
            buf = np.frombuffer(data, dtype=np.uint8, count=cut)
            if np.count_nonzero((buf == 32) | (buf == 9) | (buf == 13)):
                buf = buf[(buf != 32) & (buf != 9) & (buf != 13)]
            chunk = _parse_chunk(buf, line, where)
            for key in parts:
                parts[key].append(chunk[key])
            line += chunk["cmd"].size
    if not parts["cmd"]:
        raise InputError(f"{where}: empty trace; expected cycle,CMD,rank,bankgroup,bank,row,column lines")
    cycle = np.concatenate(parts["cycle"])
    cmd = np.concatenate(parts["cmd"])
    arrays = {k: np.concatenate(parts[k]) for k in ("rank", "bankgroup", "bank", "row", "column")}
    back = np.flatnonzero(np.diff(cycle) < 0)
    if back.size:
        i = int(back[0]) + 1
        _fail(where, i + 1, f"cycle {cycle[i]} is before the previous command's cycle {cycle[i - 1]}; "
              "expected non-decreasing cycles")
    ends = np.flatnonzero(cmd == CODE["END"])
    if ends.size and ends[0] != cmd.size - 1:
        _fail(where, int(ends[0]) + 2, f"{COMMANDS[cmd[ends[0] + 1]]} after END (line {ends[0] + 1}); "
              "expected END to be the last command")
    for key, limit in (("rank", 65535), ("bankgroup", 65535), ("bank", 65535)):
        over = arrays[key] > limit
        if over.any():
            i = int(np.argmax(over))
            _fail(where, i + 1, f"{key} {arrays[key][i]} out of range")
    trace = CommandTrace(
        path=where, cycle=cycle, cmd=cmd,
        rank=arrays["rank"].astype(np.uint16), bankgroup=arrays["bankgroup"].astype(np.uint16),
        bank=arrays["bank"].astype(np.uint16), row=arrays["row"].astype(np.uint32),
        column=arrays["column"].astype(np.uint32), end_cycle=int(cycle[-1]))
    if spec is not None:
        check_ranges(spec, trace, full=True)
    return trace


def check_ranges(spec: MemSpec, trace: CommandTrace, *, full: bool = False) -> None:
    """Raise an InputError (with the line number) for a rank or bank beyond the memspec.

    Args:
        full: also check bank groups, rows and columns.
    """
    limits = [("rank", trace.rank, spec.nbr_of_ranks), ("bank", trace.bank, spec.nbr_of_banks)]
    if full:
        limits += [("bankgroup", trace.bankgroup, spec.nbr_of_bankgroups), ("row", trace.row, spec.nbr_of_rows),
                   ("column", trace.column, spec.nbr_of_columns)]
    for name, values, limit in limits:
        over = values >= limit
        if over.any():
            i = int(np.argmax(over))
            _fail(trace.path, i + 1, f"{name} {values[i]} out of range; memspec {spec.memory_id!r} has "
                  f"{limit} ({name} 0..{limit - 1})")


def trace_stats(spec: MemSpec, trace: CommandTrace) -> CommandStats:
    """Per-rank command counts and state residency of a trace (DRAMPower v6 DDR4 state machine).

    See :mod:`hdeem_watch.dram.trace_state` for the rules.

    Raises:
        InputError: a rank or bank out of range, or power-down/self-refresh commands out of order.
    """
    from hdeem_watch.dram.trace_state import command_stats

    check_ranges(spec, trace)
    return command_stats(spec, trace)
