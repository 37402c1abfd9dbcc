"""``hdeem-watch calib show|reset|export`` against a real daemon (the sim source, ipc endpoints in a
temporary directory): show prints the fit, export writes a RUNS.json that ``hdeem-watch calibrate``
reads back to the daemon's own fit, reset forgets the runs; bad input is exit 2."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from hdeem_watch.cli import main
from hdeem_watch.wire.client import ControlClient, DaemonUnreachable

SRC = Path(__file__).resolve().parents[2] / "src"


@pytest.fixture
def daemon(tmp_path: Path) -> Iterator[str]:
    """A sim daemon at speed 20; yields its control endpoint; terminated at the end."""
    control = f"ipc://{tmp_path}/c.sock"
    env = {k: v for k, v in os.environ.items() if not k.startswith("HDEEM_WATCH_")}
    env["PYTHONPATH"] = str(SRC) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    with open(tmp_path / "daemon.err", "wb") as err:
        proc = subprocess.Popen([sys.executable, "-m", "hdeem_watch", "daemon", "--source", "sim", "--speed", "20",
                                 "--pub", f"ipc://{tmp_path}/p.sock", "--control", control,
                                 "--state-dir", str(tmp_path / "state"), "--node", "calibtest"],
                                env=env, stdout=subprocess.DEVNULL, stderr=err)
    try:
        deadline = time.monotonic() + 30
        with ControlClient(control, timeout_s=1.0) as client:
            while True:
                assert proc.poll() is None, (tmp_path / "daemon.err").read_text()
                try:
                    client.call("ping")
                    break
                except DaemonUnreachable:
                    assert time.monotonic() < deadline
                    time.sleep(0.05)
        yield control
    finally:
        proc.terminate()
        proc.wait(timeout=15)


def _runs(control: str) -> None:
    """Eight runs of different kinds (enough rows for the six unknowns of the fit)."""
    with ControlClient(control, timeout_s=30.0) as client:
        for kernel, threads in (("idle", 1), ("read", 4), ("triad", 24), ("copy", 12), ("read", 24),
                                ("assign", 6), ("idle", 1), ("add", 18)):
            run = client.call("run.start", {"kernel": kernel, "threads": threads, "elements": 1 << 22, "repeat": 2})
            time.sleep(0.25)
            client.call("run.stop", {"run_id": run["run_id"]})


def _short_run(control: str) -> None:
    """A run far too short to measure (the guard rail refuses it)."""
    with ControlClient(control, timeout_s=30.0) as client:
        run = client.call("run.start", {"kernel": "read", "threads": 2, "elements": 1 << 20, "repeat": 1})
        client.call("run.stop", {"run_id": run["run_id"]})


@pytest.mark.slow
def test_show_export_calibrate_round_trip_and_reset(daemon: str, tmp_path: Path, capsys) -> None:
    _runs(daemon)
    _short_run(daemon)
    time.sleep(0.5)  # the model worker has the refused run
    assert main(["calib", "show", "--connect", daemon, "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    node_fit = shown["node"]["fit"]
    assert node_fit["n_runs"] == 8
    assert node_fit["trust"]["commands"] == "counted"  # the daemon's default on the sim: its counters
    node_skipped = [s for s in shown["skipped"] if s["group"] == "node"]
    assert [s["name"].split(":")[1] for s in node_skipped] == ["read"] and "samples" in node_skipped[0]["reason"]
    assert main(["calib", "show", "--connect", daemon]) == 0
    text = capsys.readouterr().out
    assert text.startswith("node: 8 runs") and "idd3n" in text
    assert "commands counted in each run's window" in text and "not fitted: " in text

    runs_json = tmp_path / "RUNS.json"
    assert main(["calib", "export", "--connect", daemon, "--out", str(runs_json)]) == 0
    assert "8 fitted runs written" in capsys.readouterr().out
    exported = json.loads(runs_json.read_text())
    assert len(exported["runs"]) == 8 and set(exported["runs"][0]["columns"]) >= {"idd0", "idd3n"}
    assert len(exported["not_fitted"]) == 1 and "samples" in exported["not_fitted"][0]["reason"]
    assert exported["calibration"] == {"currents": list(node_fit["currents"]), "trust": True}
    assert main(["calibrate", "--runs", str(runs_json), "--json"]) == 0
    refit = json.loads(capsys.readouterr().out)
    for name, entry in node_fit["currents"].items():  # the same rows, the same fit, the same intervals
        assert refit["currents"][name]["calibrated"] == pytest.approx(entry["calibrated"], rel=1e-6, abs=1e-9)
        assert refit["currents"][name]["ci95"] == pytest.approx(entry["ci95"], rel=1e-6, abs=1e-9)
        assert refit["currents"][name]["identifiable"] == entry["identifiable"]
    assert refit["error"]["after"] == pytest.approx(node_fit["error"]["after"], rel=1e-6)

    assert main(["calib", "show", "--connect", daemon, "--group", "DDR_XY"]) == 2
    assert "--group DDR_XY: unknown group" in capsys.readouterr().err
    assert main(["calib", "reset", "--connect", daemon]) == 2  # issue 28: forgetting the runs needs --yes
    assert "add --yes to confirm" in capsys.readouterr().err
    assert main(["calib", "reset", "--connect", daemon, "--yes"]) == 0
    assert "calibration reset" in capsys.readouterr().out
    assert main(["calib", "show", "--connect", daemon, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["node"]["fit"] is None
    # the runs stay stored, but the fit holds none of them: nothing it fitted to export
    assert main(["calib", "export", "--connect", daemon, "--out", str(tmp_path / "again.json")]) == 2
    assert "holds no runs (9 finished runs not fitted" in capsys.readouterr().err


@pytest.mark.parametrize("action", [["show"], ["reset", "--yes"], ["export", "--out", "x.json"]])
def test_a_garbage_endpoint_is_one_line_exit_2(action: list[str], capsys) -> None:
    """Issue 28: `calib ... --connect garbage` was a ZMQError traceback."""
    assert main(["calib", *action, "--connect", "garbage"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--connect 'garbage': expected a control endpoint" in err


def test_calib_takes_the_curve_key_options_of_every_client(capsys) -> None:
    """Issue 28: one meaning per flag: calib takes --server-key/--client-key like tui, bench, jobs
    and run (a key file that does not exist is bad input naming it)."""
    assert main(["calib", "show", "--connect", "tcp://127.0.0.1:5591", "--server-key", "/nonexistent.key"]) == 2
    assert "/nonexistent.key" in capsys.readouterr().err


def test_unreachable_daemon_is_one_line_exit_1(tmp_path: Path, capsys) -> None:
    assert main(["calib", "show", "--connect", f"ipc://{tmp_path}/none.sock", "--timeout", "0.2"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no reply from the daemon" in err


@pytest.mark.parametrize(("run", "message"), [
    ({"columns": {"idd9": 1.0}}, "columns.idd9: unknown current"),
    ({"columns": {"idd0": "1"}}, "columns.idd0 = '1'; expected a finite number"),
    ({"columns": {"idd0": 1.0}, "constant_j": None}, "constant_j = None"),
    ({"columns": {"idd0": 1.0}, "stats": {"ranks": []}}, "give columns, trace or stats, not several"),
    ({"constant_j": 1.0, "stats": {"ranks": []}}, "constant_j belongs to a 'columns' row"),
])
def test_bad_model_rows_are_one_line_exit_2(tmp_path: Path, capsys, run: dict, message: str) -> None:
    path = tmp_path / "RUNS.json"
    path.write_text(json.dumps({"memspec": "samsung-m393a1g43db0-cpb",
                                "runs": [{"name": "x", "measured_j": 5.0, **run}]}))
    assert main(["calibrate", "--runs", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err
