"""``hdeem-watch calibrate``: RUNS.json in, table / JSON contract / calibrated memspec out, and
one-line errors with exit code 2 for bad input."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hdeem_watch.cli import main
from hdeem_watch.dram.command_trace import read_command_trace
from hdeem_watch.dram.energy import core_energy
from hdeem_watch.dram.memspec import load_memspec
from hdeem_watch.dram.stats import stretch_stats
from hdeem_watch.dram.trace_state import trace_stats

REFERENCE = Path(__file__).resolve().parents[1] / "data" / "drampower"
MEMSPEC = REFERENCE / "memspecs" / "ddr4_2133_x8_2r_8dev.json"
RATIOS = {"idd0": 0.55, "idd2n": 0.6, "idd3n": 0.7, "idd4r": 0.5, "idd4w": 0.45}  # physical: IDD3N 29.2 >= IDD2N 21.6 mA


def _write_runs(tmp_path: Path, synth, *, read_only: bool = False, n_kernel: int = 12, extra: dict | None = None,
                traces: bool = True, ratios: dict[str, float] | None = None) -> tuple[Path, dict[str, float]]:
    """A RUNS.json (memspec and traces copied next to it, relative paths) measured on a hidden
    truth; returns its path and the truth."""
    shutil.copy(MEMSPEC, tmp_path / "M.json")
    spec = load_memspec(MEMSPEC)
    truth = {n: spec.currents[n] * r for n, r in (ratios or RATIOS).items()}
    truth_spec = spec.with_currents(truth)
    rng = np.random.default_rng(4)
    runs = []
    planned = synth.realistic_runs(spec, rng, n_kernel=n_kernel, n_idle=2)
    if read_only:
        planned = [(f"read-{t}-{p}", synth.kernel_command_stats(spec, "read", t, 0.5 + 0.1 * t, pattern=p), 1.0)
                   for t in (1, 2, 4, 8, 12, 24) for p in ("stream", "random")] + planned[-2:]
    for name, stats, window in planned:
        energy = core_energy(truth_spec, stretch_stats(spec, stats, window)).core_j * 2 + 0.01
        runs.append({"name": name, "measured_j": energy, "stats": stats.to_dict(), "window_s": window, "scale": 2})
    if traces:
        (tmp_path / "traces").mkdir()
        for trace_name in ("stream_read", "idle_refresh"):
            src = REFERENCE / "traces" / f"{trace_name}.csv"
            shutil.copy(src, tmp_path / "traces" / src.name)
            stats = trace_stats(spec, read_command_trace(src))
            runs.append({"name": trace_name, "measured_j": core_energy(truth_spec, stats).core_j * 2 + 0.01,
                         "trace": f"traces/{src.name}", "scale": 2})
    data = {"memspec": "M.json", "runs": runs, **(extra or {})}
    path = tmp_path / "RUNS.json"
    path.write_text(json.dumps(data))
    return path, truth


def test_json_contract_and_recovered_truth(tmp_path, synth, capsys) -> None:
    """--json prints exactly one JSON object with the §7 keys; traces and statistics rows
    (relative paths, scale 2) recover the hidden currents and the intercept."""
    runs, truth = _write_runs(tmp_path, synth)
    assert main(["calibrate", "--runs", str(runs), "--json"]) == 0
    out = capsys.readouterr().out
    assert out.count("\n") == 1
    data = json.loads(out)
    for name, value in truth.items():
        entry = data["currents"][name]
        assert set(entry) >= {"datasheet", "calibrated", "ci95", "identifiable"}
        # rel 1e-5: the two trace rows refresh window/tREFI times in the model but a whole number
        # of REF commands in the trace (a sub-ppm mismatch, times the condition number ~1.7e3)
        assert entry["calibrated"] == pytest.approx(value, rel=1e-5)
    assert data["intercept_j"] == pytest.approx(0.01, rel=1e-3)
    assert set(data["error"]) == {"before", "after", "loo"}
    assert data["error"]["after"] < 1e-6 < data["error"]["before"]
    assert data["observability"]["condition_number"] > 1
    assert len(data["observability"]["singular_values"]) == 6


def test_table_and_written_memspec(tmp_path, synth, capsys) -> None:
    """The default output is a table naming every current and the errors; --write-memspec
    writes a DRAMPower memspec with the calibrated currents and everything else unchanged."""
    runs, truth = _write_runs(tmp_path, synth)
    out_spec = tmp_path / "calibrated.json"
    assert main(["calibrate", "--runs", str(runs), "--currents", "idd0,idd2n,idd3n,idd4r,idd4w",
                 "--write-memspec", str(out_spec)]) == 0
    text = capsys.readouterr().out
    for name in truth:
        assert name in text
    assert "leave-one-out" in text and "condition number" in text
    written = load_memspec(out_spec)
    original = load_memspec(MEMSPEC)
    for name, value in truth.items():
        assert written.currents[name] == pytest.approx(value, rel=1e-5)
    assert written.currents["idd5b"] == original.currents["idd5b"]
    raw_new = json.loads(out_spec.read_text())["memspec"]
    raw_old = json.loads(MEMSPEC.read_text())["memspec"]
    assert raw_new["memtimingspec"] == raw_old["memtimingspec"]
    assert set(raw_new["mempowerspec"]) == set(raw_old["mempowerspec"])


def test_unphysical_fit_is_warned_marked_and_loads_only_when_allowed(tmp_path, synth, capsys) -> None:
    """Measured on currents that break an ordering between two calibrated currents (IDD3N 25 <
    IDD2N 32 mA, which no box bound can forbid): the fit says so on stderr and in the JSON, the
    written memspec is marked, refuses to load as a physical one (exit 2 from ``calibrate
    --memspec`` with the reason) and loads with --allow-unphysical."""
    ratios = dict(RATIOS, idd2n=0.9, idd3n=0.6)
    runs, truth = _write_runs(tmp_path, synth, ratios=ratios, traces=False)
    out_spec = tmp_path / "calibrated.json"
    assert main(["calibrate", "--runs", str(runs), "--json", "--write-memspec", str(out_spec)]) == 0
    captured = capsys.readouterr()
    data = json.loads(captured.out)
    assert data["physical"] is False
    assert any(v.startswith("background: IDD3N") for v in data["violations"]), data["violations"]
    assert "unphysical" in captured.err and "--allow-unphysical" in captured.err
    assert data["currents"]["idd3n"]["calibrated"] == pytest.approx(truth["idd3n"], rel=1e-6)
    mark = json.loads(out_spec.read_text())["calibration"]
    assert mark["physical"] is False and mark["violations"] == data["violations"]
    with pytest.raises(Exception, match="unphysical currents"):
        load_memspec(out_spec)
    assert load_memspec(out_spec, allow_unphysical=True).currents["idd3n"] == pytest.approx(truth["idd3n"], rel=1e-6)
    assert main(["calibrate", "--runs", str(runs), "--memspec", str(out_spec)]) == 2
    assert "unphysical currents" in capsys.readouterr().err
    assert main(["calibrate", "--runs", str(runs), "--memspec", str(out_spec), "--allow-unphysical", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["physical"] is False


def test_physical_bounds_apply_against_the_states_the_runs_use(tmp_path, synth, capsys) -> None:
    """A rule against a fixed current binds only where the runs use that current's state. No run
    here has active power-down residency: IDD3N measured below IDD3P (16.7 < 22.5 mA) is the
    effective current of what the model books as active standby, fitted as measured (the memspec
    it makes is reported unphysical). With power-down residency in the data, IDD3P bounds IDD3N."""
    from hdeem_watch.calibrate.physical import physical_bounds

    low, _truth = _write_runs(tmp_path, synth, ratios=dict(RATIOS, idd3n=0.4), traces=False)
    assert main(["calibrate", "--runs", str(low), "--json"]) == 0
    effective = json.loads(capsys.readouterr().out)
    assert effective["currents"]["idd3n"]["calibrated"] == pytest.approx(0.4 * 0.04175, rel=1e-3)
    assert effective["currents"]["idd3n"]["at_bound"] is None and effective["physical"] is False
    spec = load_memspec(MEMSPEC)
    chosen = ("idd0", "idd2n", "idd3n", "idd4r", "idd4w")
    assert physical_bounds(spec, chosen, used={*chosen, "idd5b", "idd3p"})["idd3n"][0] == pytest.approx(0.0225)
    assert physical_bounds(spec, chosen, used={*chosen, "idd5b"})["idd3n"][0] == 0.0
    assert physical_bounds(spec, chosen)["idd3n"] == (pytest.approx(0.0225), pytest.approx(0.118))


def test_rank_deficient_runs_are_solved_and_reported(tmp_path, synth, capsys) -> None:
    """Runs that never write: exit 0, IDD4W not identifiable, rank_deficient true."""
    runs, _truth = _write_runs(tmp_path, synth, read_only=True, traces=False)
    assert main(["calibrate", "--runs", str(runs), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["observability"]["rank_deficient"] is True
    assert data["currents"]["idd4w"]["identifiable"] is False
    assert data["currents"]["idd4r"]["identifiable"] is True


def _mutate(path: Path, change) -> None:
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))


BAD_CASES = {
    "missing trace": (lambda d: d["runs"][-1].update(trace="traces/nope.csv"), [], "run 'idle_refresh': trace"),
    "measured zero": (lambda d: d["runs"][0].update(measured_j=0), [], "measured_j = 0"),
    "measured text": (lambda d: d["runs"][1].update(measured_j="12 J"), [], "is not a number"),
    "measured null": (lambda d: d["runs"][1].update(measured_j=None), [], "measured_j = None"),
    "unknown current": (lambda d: None, ["--currents", "idd0,idd9"], "unknown current 'idd9'"),
    "too few runs": (lambda d: d.update(runs=d["runs"][:4]), [], "4 runs for 6 unknowns"),
    "unknown field": (lambda d: d["runs"][0].update(energy=3), [], "unknown field 'energy'"),
    "trace and stats": (lambda d: d["runs"][-1].update(stats=d["runs"][0]["stats"]), [], "exactly one of"),
    "bad scale": (lambda d: d["runs"][0].update(scale=-1), [], "scale = -1"),
    "no memspec": (lambda d: d.update(memspec="absent.json"), [], "absent.json"),
    "bad stats": (lambda d: d["runs"][0]["stats"]["ranks"][0].update(rd=-5), [], "stats.ranks[0].rd"),
}


@pytest.mark.parametrize("case", sorted(BAD_CASES))
def test_bad_input_is_one_line_and_exit_2(tmp_path, synth, capsys, case) -> None:
    """Each kind of bad input gives exit code 2 and one line on stderr naming the run/field."""
    change, extra_args, message = BAD_CASES[case]
    runs, _truth = _write_runs(tmp_path, synth)
    _mutate(runs, change)
    assert main(["calibrate", "--runs", str(runs), *extra_args]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert err.startswith("hdeem-watch: error:") and "\n" not in err
    assert message in err
    assert captured.out == ""


def test_malformed_trace_and_file_errors(tmp_path, synth, capsys) -> None:
    """A malformed trace names the run and the trace line; a RUNS.json that is not JSON names
    the file; a missing RUNS.json too — all exit 2."""
    runs, _truth = _write_runs(tmp_path, synth)
    (tmp_path / "traces" / "idle_refresh.csv").write_text("0,ACT,0,0,0,0,0\n12,FLY,0,0,0,0,0\n")
    assert main(["calibrate", "--runs", str(runs)]) == 2
    err = capsys.readouterr().err
    assert "run 'idle_refresh'" in err and "line 2" in err
    runs.write_text("{not json")
    assert main(["calibrate", "--runs", str(runs)]) == 2
    assert "invalid JSON" in capsys.readouterr().err
    assert main(["calibrate", "--runs", str(tmp_path / "none.json")]) == 2
    assert "cannot read runs file" in capsys.readouterr().err


@pytest.mark.slow
def test_real_process_exit_codes(tmp_path, synth) -> None:
    """As a real process: --json is one parseable line on stdout with exit 0; a bad energy exits 2
    with one line on stderr and nothing on stdout."""
    runs, _truth = _write_runs(tmp_path, synth, traces=False)
    done = subprocess.run([sys.executable, "-m", "hdeem_watch", "calibrate", "--runs", str(runs), "--json",
                           "--memspec", str(MEMSPEC)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert len(done.stdout.strip().splitlines()) == 1
    assert json.loads(done.stdout)["currents"]["idd0"]["identifiable"] is True
    _mutate(runs, lambda d: d["runs"][2].update(measured_j=-1.0))
    done = subprocess.run([sys.executable, "-m", "hdeem_watch", "calibrate", "--runs", str(runs)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and done.stdout == ""
    assert len(done.stderr.strip().splitlines()) == 1 and "measured_j" in done.stderr


def test_bounds_option(tmp_path, synth, capsys) -> None:
    """--bounds caps a current (reported at its upper bound); a malformed item is exit 2."""
    runs, truth = _write_runs(tmp_path, synth, traces=False)
    cap = truth["idd4r"] * 0.9
    assert main(["calibrate", "--runs", str(runs), "--json", "--bounds", f"idd4r=0:{cap}"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["currents"]["idd4r"]["calibrated"] == pytest.approx(cap)
    assert data["currents"]["idd4r"]["at_bound"] == "upper"
    assert main(["calibrate", "--runs", str(runs), "--bounds", "idd4r=zero:1"]) == 2
    assert "--bounds" in capsys.readouterr().err


@pytest.mark.parametrize(("bound", "message"), [
    ("idd4r=0.2:0", "--bounds idd4r: lower 0.2 A must be < upper 0 A"),
    ("idd4r=0:200", "--bounds idd4r: upper 200 A looks like mA; expected amperes per device (0.2)"),
    ("idd4r=-0.1:0.2", "--bounds idd4r: lower -0.1 A is negative"),
    ("idd4r=0:inf", "--bounds idd4r: 0:inf; expected finite currents"),
])
def test_implausible_bounds_are_rejected_in_plain_numbers(tmp_path, synth, capsys, bound, message) -> None:
    """Reversed, negative, infinite or milliampere bounds: exit 2, one line in plain numbers
    (issue #20: ``idd4r=0.2:0`` printed ``np.float64(0.2)``, ``idd4r=0:200`` was accepted)."""
    runs, _truth = _write_runs(tmp_path, synth, traces=False)
    assert main(["calibrate", "--runs", str(runs), "--bounds", bound]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "np." not in err and "\n" not in err


def test_energies_in_millijoules_are_warned_about(tmp_path, synth, capsys) -> None:
    """measured_j 1000x too large (mJ): the fit still runs, but stderr and the JSON say the
    energies look like mJ (issue #20: exit 0 with every current pinned, silently)."""
    runs, _truth = _write_runs(tmp_path, synth, traces=False)
    assert main(["calibrate", "--runs", str(runs), "--json"]) == 0
    captured = capsys.readouterr()
    assert captured.err == "" and json.loads(captured.out)["warnings"] == []
    _mutate(runs, lambda d: [run.update(measured_j=run["measured_j"] * 1000) for run in d["runs"]])
    assert main(["calibrate", "--runs", str(runs), "--json"]) == 0
    captured = capsys.readouterr()
    assert "warning: measured energies are a median" in captured.err
    assert "measured_j looks like mJ; expected joules" in captured.err
    assert any("looks like mJ" in w for w in json.loads(captured.out)["warnings"])


@pytest.mark.parametrize("memspec", ["ddr4-2133-x8-4gb", "preset:ddr4-2133-x8-4gb"])
def test_memspec_presets_in_both_spellings(tmp_path, synth, capsys, memspec) -> None:
    """RUNS.json and --memspec take a preset as NAME or preset:NAME, as ``model`` does (issue #20:
    RUNS.json required ``preset:`` and ``model`` rejected it)."""
    runs, _truth = _write_runs(tmp_path, synth, traces=False)
    _mutate(runs, lambda d: d.update(memspec=memspec))
    assert main(["calibrate", "--runs", str(runs), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["memspec"] == "DDR4-2133_4Gb_x8_2R_8dev_interpMicronA"
    assert main(["calibrate", "--runs", str(runs), "--json", "--memspec", memspec]) == 0
    capsys.readouterr()
    _mutate(runs, lambda d: d.update(memspec="preset:nonesuch"))
    assert main(["calibrate", "--runs", str(runs)]) == 2
    err = capsys.readouterr().err
    assert "unknown memspec preset 'nonesuch'; expected one of: ddr4-2133-x8-4gb, " in err and "[" not in err


def test_a_directory_as_trace_says_so(tmp_path, synth, capsys) -> None:
    """A run whose trace is a directory: exit 2, 'is a directory' (not 'does not exist')."""
    runs, _truth = _write_runs(tmp_path, synth)
    _mutate(runs, lambda d: d["runs"][-1].update(trace="traces"))
    assert main(["calibrate", "--runs", str(runs)]) == 2
    assert "traces: is a directory; expected a DRAMPower trace file" in capsys.readouterr().err
