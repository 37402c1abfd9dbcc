"""``hdeem-watch model``: careless input is rejected with one clear line (issue #20), counts take
bench's spellings, long runs show progress on a terminal only.

Only built-in presets are used, so these tests need no reference data.
"""

from __future__ import annotations

import json
import os
import pty
import subprocess
import sys
from pathlib import Path

import pytest

from hdeem_watch.cli import main
from hdeem_watch.cli.numbers import whole_number
from hdeem_watch.cli.progress import Progress
from hdeem_watch.dram.controller import CHUNK_REQUESTS
from hdeem_watch.dram.kernels import kernel_requests
from hdeem_watch.dram.presets import PRESETS
from hdeem_watch.dram.request_traces import write_requests

PRESET = "ddr4-2133-x8-4gb"
SRC = Path(__file__).resolve().parents[2] / "src"


def _error(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    """Run the command line; assert exit 2, nothing on stdout and one line on stderr; return it."""
    assert main(argv) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    err = captured.err.strip()
    assert err.startswith("hdeem-watch: error:") and "\n" not in err
    return err


def test_stats_of_an_empty_trace_is_rejected(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An empty request trace is bad input, as it is for ``model energy`` (was: exit 0, zeros)."""
    empty = tmp_path / "empty.trace"
    empty.write_bytes(b"")
    for fmt in ("ramulator", "ramulator2", "pinatrace", "lackey"):
        err = _error(capsys, ["model", "stats", "--trace", str(empty), "--format", fmt, "--memspec", PRESET])
        assert f"empty.trace: no memory requests in the trace; expected {fmt} lines" in err


@pytest.mark.parametrize("command", [["stats", "--format", "ramulator"], ["energy"], ["stats", "--format", "lackey"]])
def test_a_directory_as_trace_says_it_is_a_directory(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                      command: list[str]) -> None:
    """A directory given as the trace is named as a directory (was: 'no such trace file')."""
    err = _error(capsys, ["model", command[0], "--trace", str(tmp_path), *command[1:], "--memspec", PRESET])
    assert f"{tmp_path}: is a directory; expected a trace file" in err


def test_a_directory_as_memspec_says_it_is_a_directory(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A directory given as --memspec is named as a directory, not as an unknown preset."""
    csv = tmp_path / "t.csv"
    csv.write_text("0,ACT,0,0,3,100,0\n100,END,0,0,0,0,0\n")
    err = _error(capsys, ["model", "energy", "--trace", str(csv), "--memspec", str(tmp_path)])
    assert "is a directory; expected a DRAMPower JSON memspec or a preset" in err


@pytest.mark.parametrize(("option", "message"), [
    (["--elements", "0"], "argument --elements: 0 is too small; expected at least 8 doubles"),
    (["--elements", "7"], "argument --elements: 7 is too small"),
    (["--repeat", "0"], "argument --repeat: 0 is too small; expected at least 1"),
    (["--threads", "0"], "argument --threads: 0 is too small"),
    (["--channels", "0"], "argument --channels: 0 is too small"),
    (["--elements", "1e-3"], "argument --elements: '1e-3' is not a whole number"),
])
def test_kernel_counts_that_model_nothing_are_rejected(capsys: pytest.CaptureFixture[str], option: list[str],
                                                       message: str) -> None:
    """--repeat 0, --elements 0 (and < one line), --threads 0: exit 2 (was: exit 0, 0 requests)."""
    argv = {"--kernel": "triad", "--elements": "4096", "--threads": "2", "--memspec": PRESET}
    argv[option[0]] = option[1]
    err = _error(capsys, ["model", "kernel", *[part for pair in argv.items() for part in pair]])
    assert message in err


@pytest.mark.parametrize("spelling", ["1048576", "2**20", "1_048_576", "1.048576e6"])
def test_kernel_elements_take_the_spellings_bench_takes(capsys: pytest.CaptureFixture[str], spelling: str) -> None:
    """--elements 2**20, 1e6-style and 1_000 spellings are accepted and mean the same run
    (was: rejected although ``bench --elements`` takes them)."""
    assert main(["model", "kernel", "--kernel", "copy", "--elements", spelling, "--threads", "2",
                 "--memspec", PRESET, "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["elements"] == 1_048_576
    assert data["requests"] == 3 * 1_048_576 // 8  # copy: read a, read-for-ownership and write-back of c


def test_whole_number_matches_bench_spellings() -> None:
    """The shared parser reads what ``bench --elements`` documents, and refuses fractions and giants."""
    assert [whole_number(t) for t in ("100000000", "1e8", "2**27", " 1_000 ")] == [10**8, 10**8, 2**27, 1000]
    for bad in ("1.5", "nan", "inf", "2**-1", "2**100000000", "ten", ""):
        with pytest.raises(ValueError, match="not a whole number"):
            whole_number(bad)


def test_a_binary_trace_is_shown_escaped_and_short(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A binary file as a trace: the error shows an escaped, truncated excerpt, never raw control
    bytes (was: raw bytes including carriage returns, hundreds of characters)."""
    binary = tmp_path / "a.out"
    binary.write_bytes(b"\x7fELF\x02\x01\x01\x00" + bytes(range(256)) * 4)
    crlf = tmp_path / "cr.trace"
    crlf.write_bytes(b"0x12\r\x1b[2J34 R\n")
    for path, argv in ((binary, ["stats", "--format", "ramulator"]), (binary, ["stats", "--format", "lackey"]),
                       (binary, ["energy"]), (crlf, ["stats", "--format", "ramulator"]),
                       (crlf, ["stats", "--format", "pinatrace"])):
        err = _error(capsys, ["model", argv[0], "--trace", str(path), *argv[1:], "--memspec", PRESET])
        assert not any(ord(c) < 0x20 or ord(c) > 0x7E for c in err), err
        assert len(err) < 200 + len(str(path)), err
    assert "'0x12\\r\\x1b[2J34 R'" in err


@pytest.mark.parametrize("memspec", [PRESET, f"preset:{PRESET}"])
def test_presets_in_both_spellings(tmp_path: Path, capsys: pytest.CaptureFixture[str], memspec: str) -> None:
    """``--memspec NAME`` and ``--memspec preset:NAME`` (RUNS.json's spelling) both work for
    energy, stats and kernel (was: ``preset:`` rejected)."""
    csv = tmp_path / "t.csv"
    csv.write_text("0,ACT,0,0,3,100,0\n15,RD,0,0,3,100,0\n40,PRE,0,0,3,100,0\n100,END,0,0,0,0,0\n")
    assert main(["model", "energy", "--trace", str(csv), "--memspec", memspec, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["memory_id"] == "DDR4-2133_4Gb_x8_2R_8dev_interpMicronA"
    assert main(["model", "stats", "--trace", str(csv), "--format", "drampower", "--memspec", memspec]) == 0
    assert main(["model", "kernel", "--kernel", "read", "--elements", "4096", "--threads", "1",
                 "--memspec", memspec]) == 0


@pytest.mark.parametrize(("memspec", "message"), [
    ("preset:nonesuch", "--memspec 'preset:nonesuch': unknown preset 'nonesuch'; expected one of: "
                        + ", ".join(sorted(PRESETS))),
    ("nonesuch", "--memspec 'nonesuch': no such file and no such preset"),
])
def test_unknown_presets_are_listed_plainly(tmp_path: Path, capsys: pytest.CaptureFixture[str], memspec: str,
                                            message: str) -> None:
    """An unknown preset lists the known ones as words, not as a Python list."""
    csv = tmp_path / "t.csv"
    csv.write_text("0,ACT,0,0,3,100,0\n100,END,0,0,0,0,0\n")
    err = _error(capsys, ["model", "energy", "--trace", str(csv), "--memspec", memspec])
    assert message in err and "[" not in err


def test_model_without_subcommand_shows_model_usage(capsys: pytest.CaptureFixture[str]) -> None:
    """``hdeem-watch model`` alone prints model's own usage (its three commands), exit 2 (was: the
    top-level usage)."""
    assert main(["model"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: hdeem-watch model ")
    assert all(name in err for name in ("energy", "stats", "kernel")) and "calibrate" not in err


class _Terminal:
    """A text stream that says it is a terminal and records what was written."""

    def __init__(self) -> None:
        self.text = ""

    def isatty(self) -> bool:
        return True

    def write(self, text: str) -> int:
        self.text += text
        return len(text)

    def flush(self) -> None:
        pass


def test_progress_repaints_at_most_every_tenth_of_a_second_and_always_at_the_end() -> None:
    """Updates faster than 0.1 s are skipped except the last one; clear erases the line."""
    clock = iter([0.0, 0.05, 0.2, 0.21])
    terminal = _Terminal()
    progress = Progress(terminal, clock=lambda: next(clock))  # type: ignore[arg-type]
    for done in (1, 2, 3, 4):
        progress.update("work", done, 4)
    assert terminal.text.count("\r[") == 3  # 1 (first), 3 (0.2 s later), 4 (the end); 2 skipped
    assert terminal.text.rstrip().endswith("100.0 % work")
    progress.clear()
    assert terminal.text.endswith("\r\x1b[K")


def _long_trace(tmp_path: Path) -> Path:
    trace = tmp_path / "long.trace"
    write_requests(trace, *kernel_requests("copy", 8 * (CHUNK_REQUESTS * 2 // 3 + 1), threads=2))
    return trace  # > 2 chunks of the controller model


def _on_a_terminal(argv: list[str]) -> tuple[int, bytes, bytes]:
    """Run ``hdeem-watch argv`` with stderr on a real pseudo-terminal: (exit code, stdout, terminal)."""
    main_fd, terminal_fd = pty.openpty()
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    with subprocess.Popen([sys.executable, "-m", "hdeem_watch", *argv], stdout=subprocess.PIPE,
                          stderr=terminal_fd, env=env) as process:
        os.close(terminal_fd)
        drawn = b""
        while True:
            try:
                chunk = os.read(main_fd, 4096)
            except OSError:  # the terminal closed: the process has exited
                break
            if not chunk:
                break
            drawn += chunk
        out = process.stdout.read() if process.stdout else b""
    os.close(main_fd)
    return process.returncode, out, drawn


@pytest.mark.slow
def test_stats_progress_on_a_terminal(tmp_path: Path) -> None:
    """On a real pseudo-terminal, ``model stats --emit-drampower`` draws a bar for the controller
    model and for writing, and erases it; the JSON on stdout is untouched (was: a blank screen)."""
    trace = _long_trace(tmp_path)
    code, out, drawn = _on_a_terminal(["model", "stats", "--trace", str(trace), "--format", "ramulator",
                                       "--memspec", PRESET, "--emit-drampower", str(tmp_path / "out.csv"),
                                       "--json"])
    assert code == 0
    assert json.loads(out)["requests"] == 3 * (CHUNK_REQUESTS * 2 // 3 + 1)
    assert b"controller model" in drawn and b"writing DRAMPower trace" in drawn and b"100.0 %" in drawn
    assert drawn.endswith(b"\r\x1b[K")


@pytest.mark.slow
def test_cpu_trace_progress_covers_reading_and_the_cache(tmp_path: Path) -> None:
    """A lackey trace (read line by line in Python: minutes for a real multi-GB one) reports
    reading, splitting into cache lines and the cache filter, then the controller model."""
    trace = tmp_path / "lackey.out"
    trace.write_text("==1== Lackey\n" + "".join(f" L {0x10000000 + 64 * i:08x},8\n S {0x20000000 + 64 * i:08x},8\n"
                                                for i in range(50_000)))
    code, out, drawn = _on_a_terminal(["model", "stats", "--trace", str(trace), "--format", "lackey",
                                       "--memspec", PRESET, "--json"])
    assert code == 0 and json.loads(out)["cpu_accesses"] == 100_000
    for phase in (b"reading trace", b"cache lines", b"cache filter", b"controller model"):
        assert phase in drawn, phase


@pytest.mark.slow
def test_stats_progress_is_silent_when_stderr_is_not_a_terminal(tmp_path: Path) -> None:
    """Piped stderr (a batch job's log) gets no progress bar."""
    trace = _long_trace(tmp_path)
    done = subprocess.run([sys.executable, "-m", "hdeem_watch", "model", "stats", "--trace", str(trace),
                           "--format", "ramulator", "--memspec", PRESET, "--json"],
                          capture_output=True, env={**os.environ, "PYTHONPATH": str(SRC)}, timeout=120)
    assert done.returncode == 0 and done.stderr == b""
