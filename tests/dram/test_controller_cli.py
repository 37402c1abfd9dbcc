"""``hdeem-watch model stats`` and ``model kernel``: JSON contract, DRAMPower emission, bad input."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from hdeem_watch.cli import main
from hdeem_watch.dram.kernels import kernel_requests
from hdeem_watch.dram.request_traces import write_requests

REFERENCE = Path(__file__).resolve().parents[1] / "data" / "ramulator"
MEMSPEC = str(REFERENCE / "ddr4_2133P_8Gb_x8_2r_8dev.json")
KEYS = {"requests", "reads", "writes", "act", "pre", "ref", "row_hits", "row_misses", "row_conflicts", "cycles"}


def test_stats_json_and_emitted_trace_agree(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """model stats --json has the contract keys; its emitted DRAMPower trace gives the same energy via model energy."""
    trace = tmp_path / "copy.trace"
    write_requests(trace, *kernel_requests("copy", 8 * 10_000, threads=2))
    out_csv = tmp_path / "cmd.csv"
    assert main(["model", "stats", "--trace", str(trace), "--format", "ramulator", "--memspec", MEMSPEC,
                 "--emit-drampower", str(out_csv), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert set(data) >= KEYS
    assert (data["requests"], data["reads"], data["writes"]) == (30_000, 20_000, 10_000)
    assert data["row_hits"] + data["row_misses"] + data["row_conflicts"] == data["requests"]
    assert len(data["ranks"]) == 2 and data["act"] == sum(r["act"] for r in data["ranks"])
    assert main(["model", "energy", "--trace", str(out_csv), "--memspec", MEMSPEC, "--json"]) == 0
    energy = json.loads(capsys.readouterr().out)
    assert energy["core_j"] == pytest.approx(data["energy"]["core_j"], rel=1e-12)
    assert main(["model", "stats", "--trace", str(out_csv), "--format", "drampower", "--memspec", MEMSPEC,
                 "--json"]) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["act"] == data["act"] and again["cycles"] == data["cycles"]


def test_kernel_json(capsys: pytest.CaptureFixture[str]) -> None:
    """model kernel --json: reads/writes per the kernel's traffic, commands scaled to the whole run."""
    assert main(["model", "kernel", "--kernel", "addition", "--elements", str(8 * 1_000_000), "--threads", "4",
                 "--memspec", MEMSPEC, "--repeat", "2", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert set(data) >= KEYS
    assert data["kernel"] == "add" and data["reads"] == 6_000_000 and data["writes"] == 2_000_000
    assert data["act"] > 0 and data["cycles"] > data["requests"] * 4
    assert data["energy"]["core_j"] > 0


@pytest.mark.parametrize("argv", [
    ["model", "kernel", "--kernel", "nope", "--elements", "8", "--threads", "1", "--memspec", MEMSPEC],
    ["model", "kernel", "--kernel", "copy", "--elements", "-8", "--threads", "1", "--memspec", MEMSPEC],
    ["model", "kernel", "--kernel", "copy", "--elements", "8", "--threads", "0", "--memspec", MEMSPEC],
    ["model", "stats", "--trace", "/nonexistent", "--format", "ramulator", "--memspec", MEMSPEC],
    ["model", "stats", "--trace", MEMSPEC, "--format", "ramulator", "--memspec", MEMSPEC],
    ["model", "stats", "--trace", MEMSPEC, "--format", "ramulator", "--memspec", MEMSPEC, "--mapping", "RoXo"],
])
def test_bad_input_exits_2_with_one_line(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    """Every user error is exit code 2 with one line on stderr and nothing on stdout."""
    assert main(argv) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.count("\n") == 1 and captured.err.startswith("hdeem-watch: error:")


@pytest.mark.slow
def test_malformed_trace_line_number_through_a_real_process(tmp_path: Path) -> None:
    """The installed CLI as a real process: a malformed line 3 gives exit 2 and names file:3."""
    trace = tmp_path / "bad.lstrace"
    trace.write_text("LD 0x40\nST 0x80\nXX 0x10\n")
    done = subprocess.run([sys.executable, "-m", "hdeem_watch", "model", "stats", "--trace", str(trace),
                           "--format", "ramulator2", "--memspec", MEMSPEC, "--json"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and done.stdout == ""
    assert f"{trace}:3:" in done.stderr and done.stderr.count("\n") == 1
