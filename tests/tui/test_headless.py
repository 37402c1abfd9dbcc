"""Text progress (``--headless``, ``TERM=dumb``): widths, first values, history, unreachable nodes."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import time

import numpy as np
import pytest

from hdeem_watch.tui.headless import ProgressPrinter, fit_width
from hdeem_watch.tui.model import NodeModel
from hdeem_watch.tui.records import calib_view
from hdeem_watch.tui.snapshot import NodeSnapshot
from hdeem_watch.wire import protocol

DRAM = ("DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH")
TRUTH = {"simulated": True, "mean_currents_a": {n: 0.04 for n in ("idd0", "idd2n", "idd3n", "idd4r", "idd4w")},
         "effective_currents_a": {n: 0.045 for n in ("idd0", "idd2n", "idd3n", "idd4r", "idd4w")}}
FIT = {"currents": {n: {"datasheet": 0.0622, "calibrated": 0.0451, "identifiable": n != "idd4w"} for n in TRUTH["mean_currents_a"]},
       "error": {"before": 0.632, "after": 0.004, "loo": 0.005}, "n_runs": 27, "dof": 21}


def _snapshot(model: NodeModel) -> NodeSnapshot:
    return model.snapshot(now_mono_ns=0, now_wall_ns=10**18, window_s=10, width=None)


def test_every_line_fits_the_terminal_width() -> None:
    """A calibration with five currents and the sim's truth was one line of ~330 characters; at 80
    columns every line fits and no field is lost."""
    model = NodeModel("ipc:///x")
    model.apply_calib({"fit": FIT, "truth": TRUTH, "suggest": [["copy-1t", 0.4]]})
    model.add_runs([{"run_id": "r1", "state": "done", "name": "read-1t", "kernel": "read", "threads": 1, "window_s": 1.02,
                     "dram_energy_j": 6.82, "model": {"datasheet_j": 12.83, "calibrated_j": 6.99}}])
    lines = ProgressPrinter(width=80).lines(_snapshot(model), now_s=0.0)
    assert lines and max(len(line) for line in lines) <= 80
    text = " ".join(lines)
    for field in ("measured 6.82 J", "calibrated 6.99 J", "idd4w 62.2->45.1", "suggested next run: copy-1t"):
        assert field in text, field
    assert fit_width(["x" * 100], 40) == ["x" * 33, " " * 7 + "x" * 33, " " * 7 + "x" * 33, " " * 7 + "x"]


def test_the_first_power_line_has_values() -> None:
    """Channels known from the status heartbeat before any sample gave a power line of dashes only;
    the first power line now waits for a value."""
    model = NodeModel("ipc:///x")
    model.apply_status({"channels": {name: {"rate_hz": 100.0, "status": "ok"} for name in DRAM}})
    printer = ProgressPrinter(power_every_s=5.0)
    assert not [line for line in printer.lines(_snapshot(model), now_s=0.0) if line.startswith("power")]
    for name in DRAM:
        t = 10**18 - np.arange(50, 0, -1, dtype=np.int64) * 10_000_000
        frames = protocol.encode_samples("n1", name, seq=0, rate_hz=100.0, t_wall_ns=t, power_w=np.full(50, 2.0),
                                         energy_j=1.0, status="ok", t_ns=int(t[-1]))
        model.apply(protocol.decode(frames), 0)
    power = [line for line in printer.lines(_snapshot(model), now_s=0.5) if line.startswith("power")]
    assert len(power) == 1 and all(f"{name} 2.00 W" in power[0] for name in DRAM)


def test_stored_runs_are_summed_up_not_replayed_as_new() -> None:
    """Runs the daemon had stored (a reused --state-dir) are one line, not 50 run lines newest first;
    runs that finish afterwards are printed."""
    model = NodeModel("ipc:///x")
    old = [{"run_id": f"r{i}", "state": "done", "name": f"copy-{i}", "kernel": "copy", "threads": 1, "window_s": 1.0,
            "dram_energy_j": 1.0} for i in range(50)]
    model.add_runs(old, history=True)
    printer = ProgressPrinter()
    lines = printer.lines(_snapshot(model), now_s=0.0)
    assert [line for line in lines if line.startswith("run ")] == []
    assert any(line.startswith("runs   50 earlier runs") and "copy-49" in line for line in lines)
    model.apply_run_event({"event": "stop", "run": {"run_id": "r50", "state": "done", "name": "triad-4t", "kernel": "triad",
                                                    "threads": 4, "window_s": 1.0, "dram_energy_j": 2.0}})
    new = [line for line in printer.lines(_snapshot(model), now_s=1.0) if line.startswith("run")]
    assert len(new) == 1 and "triad-4t" in new[0]


def test_runs_list_order_is_oldest_first_in_the_model() -> None:
    """runs.list is newest first; the model (and the panel, newest on top) gets them in time order."""
    from hdeem_watch.tui.feed import NodeFeed

    feed = NodeFeed("ipc:///nonexistent/control.sock")
    feed._apply_runs({"runs": [{"run_id": f"r{i}", "state": "done", "kernel": "copy", "t_stop_ns": i} for i in (3, 2, 1)]})
    assert [r.run_id for r in _snapshot(feed.model).runs] == ["r1", "r2", "r3"]


def test_an_undetermined_calibration_prints_no_after_error() -> None:
    """A fit with fewer runs than unknowns prints "after – (not determined yet)" and no loo."""
    from hdeem_watch.tui.headless import calib_line

    line = calib_line(calib_view({"fit": {**FIT, "n_runs": 2, "dof": -4,
                                          "error": {"before": 0.6, "after": 0.0, "loo": 23.79}}}))
    assert "after – (not determined yet)" in line and "loo" not in line and "2379" not in line


@pytest.mark.slow
def test_an_unreachable_daemon_is_an_error_not_exit_0(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """tui --headless against nothing: the state line names the endpoint and the reason, stderr says
    unreachable, and the exit code is 1 (it was "state ? connecting" and exit 0)."""
    endpoint = f"ipc://{tmp_path}/control.sock"
    started = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-m", "hdeem_watch", "tui", "--headless", "--connect", endpoint, "--duration", "3"],
        capture_output=True, text=True, timeout=60, env={**os.environ, "COLUMNS": "400"},
    )  # fmt: skip
    assert done.returncode == 1, (done.stdout, done.stderr)
    assert time.monotonic() - started < 30
    assert f"state  {endpoint} connecting  (no daemon socket at {tmp_path}" in done.stdout, done.stdout
    assert "unreachable" in done.stderr and endpoint in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1


@pytest.mark.slow
def test_stats_file_that_cannot_be_written_is_bad_input(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """tui --stats /nonexistent/x.jsonl: one line, exit 2, before anything starts (it was a thread
    traceback over the UI and exit 0)."""
    done = subprocess.run(
        [sys.executable, "-m", "hdeem_watch", "tui", "--stats", "/nonexistent/x.jsonl",
         "--connect", f"ipc://{tmp_path}/control.sock", "--duration", "1"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines() == [done.stderr.strip()]
    assert "--stats /nonexistent/x.jsonl" in done.stderr and "Traceback" not in done.stderr
    assert done.stdout == ""


def test_a_nan_power_never_prints_as_zero() -> None:
    """Unknown stays unknown in the text lines too."""
    from hdeem_watch.tui.headless import power_line

    model = NodeModel("ipc:///x")
    model.apply_status({"channels": {"DDR_AB": {"rate_hz": 100.0}}})
    line = power_line(_snapshot(model))
    assert "DDR_AB –" in line and not math.isfinite(_snapshot(model).channels[0].power_w)


def test_hold_out_runs_are_summed_up_in_one_line() -> None:
    """Runs of hold-out kernels (never fitted) count into the closing ``holdout:`` line with the
    prediction from before each; other runs do not, and none counts before it has a prediction."""
    model = NodeModel("ipc:///x")
    printer = ProgressPrinter()
    assert printer.holdout_line() is None
    for i, (kernel, measured, datasheet, calibrated) in enumerate((
            ("gups", 10.0, 16.0, 10.2), ("read", 10.0, 16.0, 13.0), ("stride4", 8.0, 12.0, 7.6),
            ("chase", 5.0, 8.0, None))):
        model.apply_run_event({"event": "stop", "run": {
            "run_id": f"r{i}", "state": "done", "name": f"{kernel}-4t", "kernel": kernel, "threads": 4, "window_s": 1.5,
            "dram_energy_j": measured, "model": {"datasheet_j": datasheet, "calibrated_j": calibrated}}})
        printer.lines(_snapshot(model), now_s=float(i))
    assert printer.holdout_line() == ("holdout: 2 runs, median error 3.5 %, worst 5.0 % "
                                      "(datasheet: median 55.0 %, worst 60.0 %)")


def test_currents_carry_their_unit_and_the_baselines_are_printed() -> None:
    """Issue 28: the headless lines gave currents without a unit and never the idle baselines the
    TUI shows; currents are in mA, and each new set of baselines is one line."""
    model = NodeModel("ipc:///x")
    model.apply_calib({"fit": FIT, "truth": TRUTH})
    printer = ProgressPrinter(width=200)
    text = " ".join(printer.lines(_snapshot(model), now_s=0.0))
    assert "idd0 62.2->45.1 mA" in text and not any(line.startswith("idle") for line in text.splitlines())
    model.apply_status({"channels": {name: {"rate_hz": 100.0, "status": "ok"} for name in DRAM}})
    model.apply_baselines({"channels": {name: {"power_w": 0.5 + i / 10, "spread_w": 0.01, "origin": "idle-run"}
                                        for i, name in enumerate(DRAM)}})
    idle = [line for line in printer.lines(_snapshot(model), now_s=1.0) if line.startswith("idle")]
    assert idle == ["idle   DDR_AB 0.50 W  DDR_CD 0.60 W  DDR_EF 0.70 W  DDR_GH 0.80 W  (baselines: idle-run)"]
    assert not [line for line in printer.lines(_snapshot(model), now_s=2.0) if line.startswith("idle")]
