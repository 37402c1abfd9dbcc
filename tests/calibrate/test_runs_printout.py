"""RUNS.json runs whose measured energy comes from a real HDEEM printout (reference/taurus)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from hdeem_watch.calibrate.hdeem_printout import read_printout
from hdeem_watch.calibrate.runs_file import read_runs_file
from hdeem_watch.cli import main
from hdeem_watch.dram.stats import CommandStats, RankStats

TAURUS = Path(__file__).resolve().parents[1] / "data" / "taurus"


def _write(tmp_path: Path, runs: list[dict]) -> Path:
    path = tmp_path / "runs.json"
    path.write_text(json.dumps({"memspec": "preset:samsung-m393a1g43db0-cpb", "runs": runs}))
    return path


def _stats() -> dict:
    rank = RankStats(act=1e6, pre=1e6, rd=4e6, wr=2e6, cycles_total=1e9, cycles_act=6e8, cycles_pre=4e8)
    return CommandStats(ranks=(rank, rank)).to_dict()


def test_printout_energy_and_window_become_the_row(tmp_path: Path) -> None:
    """The row's measured energy is the printout's DDR_AB..DDR_GH energy sum and its window the block's duration."""
    printout = TAURUS / "6485taurus.txt"
    block = [b for b in read_printout(printout).of_kind("stats") if math.isfinite(b.dram_energy_j())][-1]
    path = _write(tmp_path, [{"name": "add", "hdeem_printout": str(printout), "stats": _stats(), "scale": 8}])
    _, (obs,) = read_runs_file(path)
    assert obs.measured_j == pytest.approx(block.dram_energy_j())
    assert obs.measured_j == pytest.approx(8.508)
    assert obs.window_s == pytest.approx(block.duration_s)


def test_printout_and_measured_together_is_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Giving both measured_j and hdeem_printout is a one-line error naming the run, exit code 2."""
    path = _write(tmp_path, [{"name": "x", "measured_j": 1.0, "hdeem_printout": str(TAURUS / "6415.txt"),
                              "stats": _stats()}])
    assert main(["calibrate", "--runs", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "'x'" in err and "not both" in err and "\n" not in err


def test_printout_block_out_of_range_is_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A printout_block beyond the blocks that carry DRAM energy is named in a one-line error."""
    path = _write(tmp_path, [{"name": "y", "hdeem_printout": str(TAURUS / "6415.txt"), "printout_block": 7,
                              "stats": _stats()}])
    assert main(["calibrate", "--runs", str(path)]) == 2
    assert "printout_block = 7" in capsys.readouterr().err
