"""``model energy/stats/kernel --allow-unphysical`` (issue 15): an unphysical memspec file is refused
with one line naming the currents and the flag, and loaded with the flag (to study a fit's raw output)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hdeem_watch.cli import main
from hdeem_watch.dram.memspec import preset


@pytest.fixture
def unphysical(tmp_path: Path) -> Path:
    """A preset with IDD0 below IDD3N: activation energy < 0 (as a raw fit can give)."""
    tree = preset("ddr4-2133-x8-4gb").to_json_dict()
    tree["memspec"]["mempowerspec"]["idd0"] = 0.020
    path = tmp_path / "raw-fit.json"
    path.write_text(json.dumps(tree))
    return path


@pytest.fixture
def trace(tmp_path: Path) -> Path:
    path = tmp_path / "t.csv"
    path.write_text("0,ACT,0,0,0,0,0\n40,RD,0,0,0,0,0\n80,PRE,0,0,0,0,0\n200,END,0,0,0,0,0\n")
    return path


def _argv(command: str, memspec: Path, trace: Path) -> list[str]:
    if command == "energy":
        return ["model", "energy", "--memspec", str(memspec), "--trace", str(trace), "--json"]
    if command == "stats":
        return ["model", "stats", "--format", "drampower", "--trace", str(trace), "--memspec", str(memspec), "--json"]
    return ["model", "kernel", "--kernel", "read", "--elements", "8192", "--threads", "1", "--memspec",
            str(memspec), "--json"]


@pytest.mark.parametrize("command", ["energy", "stats", "kernel"])
def test_refused_without_the_flag_loaded_with_it(command: str, unphysical: Path, trace: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """Without the flag: exit 2, one line naming IDD0 and --allow-unphysical; with it: a result whose
    activation energy is negative (the file's currents, not silently fixed)."""
    assert main(_argv(command, unphysical, trace)) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert captured.out == "" and "\n" not in err
    assert "unphysical currents" in err and "IDD0 20 mA" in err and "--allow-unphysical" in err
    assert main([*_argv(command, unphysical, trace), "--allow-unphysical"]) == 0
    data = json.loads(capsys.readouterr().out)
    components = data["components"] if command == "energy" else data["energy"]["components"]
    assert components["act_j"] < 0


def test_presets_need_no_flag(trace: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A preset is physical: the flag changes nothing for it."""
    argv = ["model", "kernel", "--kernel", "read", "--elements", "8192", "--threads", "1", "--memspec",
            "samsung-m393a1g43db0-cpb", "--json"]
    assert main(argv) == 0
    plain = json.loads(capsys.readouterr().out)
    assert main([*argv, "--allow-unphysical"]) == 0
    assert json.loads(capsys.readouterr().out) == plain
    assert plain["energy"]["components"]["act_j"] >= 0
