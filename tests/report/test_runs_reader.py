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
        assert data.fit.currents[name].calibrated_a == pytest.approx(entry["calibrated"], rel=1e-12)
    assert data.fit.error.to_dict() == pytest.approx(printed["error"])


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


def _trace(path: Path, reads: int, writes: int, rows: int, gap: int) -> None:
    """A DRAMPower command trace on both ranks: ``rows`` row cycles of ``reads`` RD and ``writes`` WR
    each, ``gap`` idle cycles between rows, a refresh every 8 rows."""
    lines, cycle = [], 0
    for i in range(rows):
        rank, bank = i % 2, i % 16
        lines.append(f"{cycle},ACT,{rank},0,{bank},{i},0")
        cycle += 15
        for k in range(reads):
            lines.append(f"{cycle},RD,{rank},0,{bank},{i},{8 * k}")
            cycle += 4
        for k in range(writes):
            lines.append(f"{cycle},WR,{rank},0,{bank},{i},{8 * k}")
            cycle += 4
        cycle += 30
        lines.append(f"{cycle},PRE,{rank},0,{bank},{i},0")
        cycle += 15 + gap
        if i % 8 == 7:
            lines.append(f"{cycle},REFA,{rank},0,0,0,0")
            cycle += 400
    lines.append(f"{cycle + 100},END,0,0,0,0,0")
    path.write_text("\n".join(lines) + "\n")


def test_trace_runs_without_times(tmp_path: Path) -> None:
    """Runs given as command traces (no time_ns) are read, fitted and drawn: their components come
    from the traces and add up to the calibrated energy; the time axes fall back to run numbers."""
    from hdeem_watch.dram.command_trace import read_command_trace
    from hdeem_watch.dram.energy import core_energy
    from hdeem_watch.dram.memspec import preset
    from hdeem_watch.dram.stats import stretch_stats
    from hdeem_watch.dram.trace_state import trace_stats
    from hdeem_watch.report.build import build_report

    spec = preset("ddr4-2133-x8-4gb")
    truth = spec.with_currents({n: spec.currents[n] * r for n, r in
                                {"idd0": 0.6, "idd2n": 0.5, "idd3n": 0.55, "idd4r": 0.55, "idd4w": 0.5}.items()})
    # (a physical truth: the calibrator's bounds keep IDD3N >= IDD2N, so an unphysical one is not reached)
    runs = []
    for i, (reads, writes, rows, gap) in enumerate([(8, 0, 64, 0), (0, 8, 64, 0), (4, 4, 64, 10), (16, 0, 32, 200),
                                                    (0, 16, 32, 200), (1, 0, 128, 0), (0, 0, 8, 3000),
                                                    (2, 6, 64, 40)]):
        path = tmp_path / f"k{i}.csv"
        _trace(path, reads, writes, rows, gap)
        stats = trace_stats(spec, read_command_trace(path))
        measured = core_energy(truth, stretch_stats(spec, stats, 1e-5)).core_j + 1e-9
        runs.append({"name": f"mix{i}-1t", "measured_j": measured, "trace": path.name, "window_s": 1e-5})
    runs_json = tmp_path / "RUNS.json"
    runs_json.write_text(json.dumps({"memspec": "preset:ddr4-2133-x8-4gb", "runs": runs}))
    data = read_runs(runs_json)
    assert [(r.kernel, r.threads) for r in data.runs][:2] == [("mix0", 1), ("mix1", 1)]
    for run in data.runs:
        parts = analysis.component_energies(data.spec, data.fit, run)
        assert sum(parts.values()) == pytest.approx(run.calibrated_j, rel=1e-9)
        assert run.calibrated_j == pytest.approx(run.measured_j, rel=1e-3)
    written = build_report(data, tmp_path / "out", fmt="svg")
    assert "run number" in (tmp_path / "out" / "fig3-residuals.svg").read_text()
    assert written.missing["fig5-components"] == ()
