"""DRAMPower CSV command traces: parsing, one-line errors with line numbers, chunking."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hdeem_watch.dram import command_trace
from hdeem_watch.dram.command_trace import COMMANDS, read_command_trace
from hdeem_watch.dram.memspec import preset
from hdeem_watch.dram.trace_state import trace_stats
from hdeem_watch.errors import InputError

GOOD = ("0,ACT,0,0,3,100,0\n"
        "15,RD,0,0,3,100,16,00aa0ddba948f454\n"
        "40,PRE,0,0,3,100,0\n"
        "41,ACT,1,3,15,32767,0\n"
        "60,WRA,1,3,15,32767,1016,ff\n"
        "100,END,0,0,0,0,0\n")


def _write(tmp_path: Path, text: str, name: str = "t.csv") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_fields_parsed(tmp_path: Path) -> None:
    """Every field of every line is parsed; the data field is optional; END gives T."""
    trace = read_command_trace(_write(tmp_path, GOOD), preset("ddr4-2133-x8-4gb"), addresses=True)
    assert len(trace) == 6 and trace.end_cycle == 100
    assert trace.cycle.tolist() == [0, 15, 40, 41, 60, 100]
    assert [COMMANDS[c] for c in trace.cmd] == ["ACT", "RD", "PRE", "ACT", "WRA", "END"]
    assert trace.rank.tolist() == [0, 0, 0, 1, 1, 0]
    assert trace.bankgroup.tolist() == [0, 0, 0, 3, 3, 0]
    assert trace.bank.tolist() == [3, 3, 3, 15, 15, 0]
    assert trace.row.tolist() == [100, 100, 100, 32767, 32767, 0]
    assert trace.column.tolist() == [0, 16, 0, 0, 1016, 0]
    assert trace.count("ACT") == 2


def test_whitespace_crlf_and_trailing_blank_lines(tmp_path: Path) -> None:
    """Spaces, tabs and CRLF line ends are ignored (DRAMPower trims); trailing blank lines are fine."""
    messy = GOOD.replace(",", " , ").replace("\n", "\r\n").replace("RD", "\tRD") + "\r\n\n  \n"
    a = read_command_trace(_write(tmp_path, GOOD, "a.csv"), addresses=True)
    b = read_command_trace(_write(tmp_path, messy, "b.csv"), addresses=True)
    for field in ("cycle", "cmd", "rank", "bank", "row", "column"):
        assert np.array_equal(getattr(a, field), getattr(b, field)), field


def test_no_end_and_no_final_newline(tmp_path: Path) -> None:
    """Without END, T is the last command's cycle; a missing final newline is accepted."""
    trace = read_command_trace(_write(tmp_path, "0,ACT,0,0,0,0,0\n77,PRE,0,0,0,0,0"))
    assert trace.end_cycle == 77 and len(trace) == 2
    stats = trace_stats(preset("ddr4-2133-x8-4gb"), trace)
    assert stats.ranks[0].cycles_act == 77 and stats.ranks[0].pre == 1


def test_chunk_boundaries_do_not_matter(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Parsing in tiny chunks (lines split across reads) gives the same arrays with correct line numbers."""
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.integers(0, 50, 3000))
    names = rng.choice(["RD", "WR", "ACT", "PRE"], 3000)
    text = "".join(f"{c},{n},{r},0,{b},{row},{col}{',abcd' if n in ('RD', 'WR') else ''}\n"
                   for c, n, r, b, row, col in zip(t, names, rng.integers(0, 2, 3000), rng.integers(0, 16, 3000),
                                                   rng.integers(0, 32768, 3000), rng.integers(0, 1024, 3000)))
    path = _write(tmp_path, text)
    whole = read_command_trace(path, addresses=True)
    monkeypatch.setattr(command_trace, "CHUNK_BYTES", 997)
    pieces = read_command_trace(path, addresses=True)
    for field in ("cycle", "cmd", "rank", "bank", "row", "column"):
        assert np.array_equal(getattr(whole, field), getattr(pieces, field)), field
    assert whole.cycle.tolist() == t.tolist()
    bad = text.splitlines()
    bad[2500] = bad[2500].replace(",", ";", 1)
    _write(tmp_path, "\n".join(bad) + "\n")
    with pytest.raises(InputError, match="line 2501: "):
        read_command_trace(path)


@pytest.mark.parametrize(("text", "message"), [
    ("0,ACT,0,0,0,0,0\n5,ACT,0,0,1,0\n", r"line 2: 6 fields in '5,ACT,0,0,1,0'; expected cycle,CMD"),
    ("0,ACT,0,0,0,0,0\n\n5,PRE,0,0,0,0,0\n", "line 2: empty line"),
    ("0,ACT,0,0,0,0,0,ab,cd\n", "line 1: 9 fields"),
    ("0,ACT,0,0,0,0,0\nx1,PRE,0,0,0,0,0\n", "line 2: cycle = 'x1' is not a non-negative integer"),
    ("0,ACT,0,0,-1,0,0\n", "line 1: bank = '-1' is not a non-negative integer"),
    ("0,ACT,a,0,0,0,0\n", "line 1: rank = 'a' is not a non-negative integer"),
    ("0,ACT,0,0,1x,0,0\n", "line 1: bank = '1x' is not a non-negative integer"),
    ("0,ACT,0,0,0,12345678901234567,0\n", "line 1: row = '12345678901234567' is not a non-negative integer"),
    ("0,ACT,0,0,0,1e5,0\n", "line 1: row = '1e5' is not a non-negative integer"),
    ("0,ACT,0,0,0,,0\n", "line 1: row = '' is not a non-negative integer"),
    ("0,ACT,0,0,0,0,0\n3,FOO,0,0,0,0,0\n", "line 2: unknown command 'FOO'; expected one of ACT, PRE"),
    ("0,REFB,0,0,0,0,0\n", r"line 1: unknown command 'REFB' \(a command of another DRAM standard\)"),
    ("0,act,0,0,0,0,0\n", "line 1: unknown command 'act'"),
    ("10,ACT,0,0,0,0,0\n9,PRE,0,0,0,0,0\n", "line 2: cycle 9 is before the previous command's cycle 10"),
    ("10,END,0,0,0,0,0\n11,PRE,0,0,0,0,0\n", r"line 2: PRE after END \(line 1\)"),
    ("", "empty trace"),
    ("\n\n", "empty trace"),
])
def test_malformed_traces_one_line_error(tmp_path: Path, text: str, message: str) -> None:
    """Malformed lines, unknown commands, decreasing cycles, commands after END: file, line, reason."""
    path = _write(tmp_path, text)
    with pytest.raises(InputError, match=message) as info:
        read_command_trace(path)
    assert "\n" not in str(info.value) and str(info.value).startswith(str(path))


@pytest.mark.parametrize(("line", "message"), [
    ("5,ACT,2,0,0,0,0", "line 2: rank 2 out of range; memspec .* has 2 \\(rank 0..1\\)"),
    ("5,ACT,0,0,16,0,0", "line 2: bank 16 out of range"),
    ("5,ACT,0,4,0,0,0", "line 2: bankgroup 4 out of range"),
    ("5,ACT,0,0,0,32768,0", "line 2: row 32768 out of range"),
    ("5,RD,0,0,0,0,1024", "line 2: column 1024 out of range"),
])
def test_addresses_out_of_range(tmp_path: Path, line: str, message: str) -> None:
    """With a memspec, ranks, bank groups, banks, rows and columns beyond it are errors with the line."""
    path = _write(tmp_path, f"0,PREA,0,0,0,0,0\n{line}\n")
    with pytest.raises(InputError, match=message):
        read_command_trace(path, preset("ddr4-2133-x8-4gb"))
    if "rank" in message or "bank " in message:  # trace_stats checks ranks and banks itself
        with pytest.raises(InputError, match=message):
            trace_stats(preset("ddr4-2133-x8-4gb"), read_command_trace(path))


def test_unreadable_file(tmp_path: Path) -> None:
    """A missing file or a directory is an InputError saying which, not a traceback."""
    with pytest.raises(InputError, match=r"nope\.csv: no such trace file"):
        read_command_trace(tmp_path / "nope.csv")
    with pytest.raises(InputError, match="is a directory; expected a trace file"):
        read_command_trace(tmp_path)


def test_addresses_optional_and_backwards_across_chunks(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Addresses are kept only on request; a decreasing cycle is caught across a chunk boundary too."""
    trace = read_command_trace(_write(tmp_path, GOOD))
    assert trace.row is None and trace.column is None and trace.bankgroup is None
    lines = [f"{10 * i},RD,0,0,0,0,0" for i in range(400)]
    lines[300] = "2985,RD,0,0,0,0,0"
    path = _write(tmp_path, "\n".join(lines) + "\n", "b.csv")
    for chunk in (1 << 24, 97, 64):
        monkeypatch.setattr(command_trace, "CHUNK_BYTES", chunk)
        with pytest.raises(InputError, match="line 301: cycle 2985 is before the previous command's cycle 2990"):
            read_command_trace(path)
