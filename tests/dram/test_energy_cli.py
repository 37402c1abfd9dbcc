"""``hdeem-watch model energy``: JSON contract, table, and one-line errors with exit code 2."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from hdeem_watch.cli import main
from hdeem_watch.dram.energy import COMPONENTS


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(["model", "energy", *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, err


def test_json_contract_and_values(capsys: pytest.CaptureFixture[str], drampower_ref: Path,  # type: ignore[no-untyped-def]
                                  reference_memspec_path) -> None:
    """--json prints exactly one object with DESIGN.md §7's keys; the core energy is DRAMPower's."""
    code, out, err = _run(capsys, "--memspec", reference_memspec_path("allterms"),
                          "--trace", drampower_ref / "traces" / "stream_read.csv", "--json")
    assert code == 0 and err == ""
    assert out.count("\n") == 1
    data = json.loads(out)
    assert {"total_j", "core_j", "interface_j", "components", "counts", "cycles"} <= data.keys()
    assert set(data["components"]) == set(COMPONENTS)
    assert data["interface_j"] is None
    internal = json.loads((drampower_ref / "results" / "allterms" / "stream_read.stats.json").read_text())
    assert data["core_j"] == pytest.approx(internal["total_core"], rel=1e-9)
    assert data["total_j"] == data["core_j"]
    assert len(data["counts"]) == 2 and set(data["counts"][0]) == {"act", "pre", "rd", "wr", "rda", "wra", "ref"}
    assert set(data["cycles"][1]) == {"act", "pre", "pdna", "pdnp", "sref"}
    for r, rank in enumerate(internal["stats"]["rank_total"]):
        assert data["cycles"][r]["act"] == rank["cycles"]["act"]
        assert data["cycles"][r]["pre"] == rank["cycles"]["pre"]
    assert data["counts"][0]["rd"] + data["counts"][1]["rd"] == sum(
        b["counter"]["reads"] for b in internal["stats"]["bank"])
    assert sum(r["core_j"] for r in data["ranks"]) == pytest.approx(data["core_j"], rel=1e-12)
    assert [r["counts"] for r in data["ranks"]] == data["counts"]
    assert [r["cycles"] for r in data["ranks"]] == data["cycles"]


def test_table_by_default_and_preset_name(capsys: pytest.CaptureFixture[str], drampower_ref: Path) -> None:
    """Without --json a readable table lists every component; a preset name works as --memspec."""
    code, out, err = _run(capsys, "--memspec", "ddr4-2133-x8-4gb", "--trace", drampower_ref / "traces" / "pdn_sref.csv")
    assert code == 0 and err == ""
    for word in ("act", "bg_pre", "pdna", "sref", "core", "interface", "not modelled", "total"):
        assert word in out
    assert not out.lstrip().startswith("{")


@pytest.mark.parametrize(("kind", "content", "message"), [
    ("memspec", "mA", "idd0 = 58.5 looks like mA"),
    ("memspec", "missing", "missing field RAS"),
    ("memspec", "json", "invalid JSON"),
    ("trace", "0,ACT,0,0,0,0,0\n5,XYZ,0,0,0,0,0\n", "line 2: unknown command 'XYZ'"),
    ("trace", "0,ACT,0,0,0,0,0\n5,PRE,7,0,0,0,0\n", "line 2: rank 7 out of range"),
    ("trace", "9,ACT,0,0,0,0,0\n5,PRE,0,0,0,0,0\n", "line 2: cycle 5 is before"),
])
def test_bad_input_is_one_line_exit_2(capsys: pytest.CaptureFixture[str], tmp_path: Path,  # type: ignore[no-untyped-def]
                                      reference_memspec_json, drampower_ref: Path,
                                      kind: str, content: str, message: str) -> None:
    """A bad memspec or a bad trace: exit code 2, one line on stderr naming the problem, nothing on stdout."""
    memspec = tmp_path / "m.json"
    trace = drampower_ref / "traces" / "pdn_sref.csv"
    if kind == "memspec":
        if content == "mA":
            reference_memspec_json["memspec"]["mempowerspec"]["idd0"] = 58.5
        elif content == "missing":
            del reference_memspec_json["memspec"]["memtimingspec"]["RAS"]
        memspec.write_text("{" if content == "json" else json.dumps(reference_memspec_json))
    else:
        memspec.write_text(json.dumps(reference_memspec_json))
        trace = tmp_path / "t.csv"
        trace.write_text(content)
    code, out, err = _run(capsys, "--memspec", memspec, "--trace", trace, "--json")
    assert code == 2 and out == ""
    assert err.startswith("hdeem-watch: error: ") and err.count("\n") == 1
    assert message in err


@pytest.mark.slow
def test_subprocess_exit_codes(tmp_path: Path, drampower_ref: Path) -> None:
    """As a real process: success prints JSON (exit 0); a bad trace gives exit 2 and one stderr line."""
    ok = subprocess.run([sys.executable, "-m", "hdeem_watch", "model", "energy", "--memspec", "ddr4-2133-x8-4gb",
                         "--trace", str(drampower_ref / "traces" / "idle_refresh.csv"), "--json"],
                        capture_output=True, text=True, timeout=60)
    assert ok.returncode == 0, ok.stderr
    assert json.loads(ok.stdout)["components"]["ref_j"] > 0
    bad = tmp_path / "bad.csv"
    bad.write_text("0,ACT,0,0,0,0\n")
    done = subprocess.run([sys.executable, "-m", "hdeem_watch", "model", "energy", "--memspec", "ddr4-2133-x8-4gb",
                           "--trace", str(bad)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.count("\n") == 1 and "line 1: 6 fields" in done.stderr
