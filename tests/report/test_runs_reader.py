"""A RUNS.json as report input: fitted the way ``hdeem-watch calibrate`` fits it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hdeem_watch.cli import main
from hdeem_watch.errors import InputError
from hdeem_watch.report import analysis
from hdeem_watch.report.runs_reader import kernel_and_threads, read_runs


def test_the_fit_is_calibrates(runs_json: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The report's fit of a RUNS.json is the one ``calibrate --json`` prints."""
    assert main(["calibrate", "--runs", str(runs_json), "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    data = read_runs(runs_json)
    assert data.fit is not None
    for name, entry in printed["currents"].items():
        assert data.fit["currents"][name]["calibrated"] == pytest.approx(entry["calibrated"], rel=1e-12)
    assert data.fit["error"] == pytest.approx(printed["error"])


def test_runs_keep_names_energies_and_statistics(runs_json: Path) -> None:
    """Each run keeps its measured energy, its kernel/threads from the name and its statistics, so
    the components of the calibrated model add up to its calibrated energy."""
    raw = json.loads(runs_json.read_text())["runs"]
    data = read_runs(runs_json)
    assert [r.measured_j for r in data.runs] == [r["measured_j"] for r in raw]
    assert [(r.kernel, r.threads) for r in data.runs][:2] == [("idle", 24), ("read", 24)]
    for run in data.runs:
        parts = analysis.component_energies(data.spec, data.fit, run)
        assert sum(parts.values()) == pytest.approx(run.calibrated_j, rel=1e-9)


def test_kernel_and_threads_from_names() -> None:
    """``kernel-Nt`` and ``kernel_Nt`` split; other names are their own kernel."""
    assert kernel_and_threads("Triad-24t") == ("triad", 24)
    assert kernel_and_threads("stream copy") == ("stream copy", 0)


def test_bad_runs_file_is_calibrates_input_error(tmp_path: Path) -> None:
    """A malformed RUNS.json fails with the calibrator's one-line message."""
    bad = tmp_path / "runs.json"
    bad.write_text('{"memspec": "preset:samsung-m393a1g43db0-cpb", "runs": [{"name": "x", "measured_j": -1}]}')
    with pytest.raises(InputError, match="measured_j"):
        read_runs(bad)
