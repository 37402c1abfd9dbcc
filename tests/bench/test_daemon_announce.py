"""The bench's run announcements against a REAL daemon process (sim source, ipc sockets)."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from hdeem_watch.wire.client import ControlClient, DaemonUnreachable

SRC = Path(__file__).resolve().parents[2] / "src"


def _env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("SLURM_")}
    env["PYTHONPATH"] = f"{SRC}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"
    return env


@pytest.fixture
def daemon(tmp_path: Path) -> Iterator[str]:
    """Start `python -m hdeem_watch daemon --source sim` on ipc sockets; yield its control endpoint."""
    pub, control = f"ipc://{tmp_path / 'pub.sock'}", f"ipc://{tmp_path / 'control.sock'}"
    log = open(tmp_path / "daemon.log", "wb")  # noqa: SIM115 - closed below
    proc = subprocess.Popen([sys.executable, "-m", "hdeem_watch", "daemon", "--source", "sim", "--pub", pub,
                             "--control", control, "--state-dir", str(tmp_path / "state")],
                            stdout=log, stderr=subprocess.STDOUT, env=_env())
    try:
        deadline = time.monotonic() + 30
        with ControlClient(control, timeout_s=1.0) as client:
            while True:
                try:
                    client.call("status")
                    break
                except DaemonUnreachable:
                    if proc.poll() is not None or time.monotonic() > deadline:
                        raise RuntimeError("daemon did not come up: "
                                           + (tmp_path / "daemon.log").read_text()[-2000:]) from None
                    time.sleep(0.1)
        yield control
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        log.close()


def test_runs_are_announced_to_a_real_daemon(daemon: str) -> None:
    """Each bench run becomes a daemon run with the same parameters, whose window encloses the
    bench's measured window, with DRAM energy integrated over it, announced with the CPUs it was
    pinned to (and modelled there); runs.list lists them."""
    proc = subprocess.run([sys.executable, "-m", "hdeem_watch", "bench", "--kernels", "triad,idle", "--threads",
                           "1", "--elements", "262144", "--repeat", "3", "--daemon", daemon, "--json"],
                          capture_output=True, text=True, timeout=120, env=_env())
    assert proc.returncode == 0, proc.stderr
    records = [json.loads(line) for line in proc.stdout.splitlines()]
    assert [r["kernel"] for r in records] == ["triad", "idle"]
    for record in records:
        run = record["daemon"]
        assert run["run_id"] == record["run_id"]
        for key in ("kernel", "threads", "elements", "repeat"):
            assert run[key] == record[key], key
        assert run["name"] == f"{record['kernel']}-1t"
        assert run["t_start_ns"] <= record["t_start_ns"] <= record["t_end_ns"] <= run["t_stop_ns"]
        # where it ran: the CPUs the workers were pinned to, and the arrays' size; the daemon modelled it there
        assert run["metadata"]["cpus"] == record["cpus"]
        if record["kernel"] == "triad":
            assert run["metadata"]["array_bytes"] == 2 * 262144 * 8  # a and b (c is the constant)
        assert run["model"]["placement"]["cpus"] == "announced cpus", run["model"]
        dram = [v for k, v in run["energy_j"].items() if k.startswith("DDR_")]
        assert len(dram) == 4 and all(v is not None and math.isfinite(v) and v > 0 for v in dram)
    with ControlClient(daemon, timeout_s=5.0) as client:
        listed = client.call("runs.list", {"limit": 10})["runs"]
    by_id = {run["run_id"]: run for run in listed}
    assert {r["run_id"] for r in records} <= set(by_id)
    assert [by_id[r["run_id"]]["kernel"] for r in records] == ["triad", "idle"]


@pytest.mark.slow
def test_bench_waits_for_a_run_open_on_a_real_daemon(daemon: str) -> None:
    """While another client's run is open the real daemon refuses run.start (conflict): the bench
    waits and retries; with too short a wait it exits 1 with one error line; once the other run
    stops it announces its own and gets its energies (exit 0)."""
    command = [sys.executable, "-m", "hdeem_watch", "bench", "--kernels", "read", "--threads", "1",
               "--elements", "65536", "--repeat", "2", "--daemon", daemon, "--json"]
    with ControlClient(daemon, timeout_s=5.0) as client:
        other = client.call("run.start", {"kernel": "copy", "name": "someone-else"})["run_id"]
        refused = subprocess.run([*command, "--wait", "1"], capture_output=True, text=True, timeout=60, env=_env())
        assert refused.returncode == 1 and refused.stdout == ""
        assert "Traceback" not in refused.stderr
        assert f"run {other} is in progress" in refused.stderr.strip().splitlines()[-1]
        waiting = subprocess.Popen([*command, "--wait", "60"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                   text=True, env=_env())
        time.sleep(2.0)
        client.call("run.stop", {"run_id": other})
    out, err = waiting.communicate(timeout=60)
    assert waiting.returncode == 0, err
    assert "waiting up to 60 s" in err
    (record,) = [json.loads(line) for line in out.splitlines()]
    assert record["run_id"] != other and record["daemon"]["run_id"] == record["run_id"]
    dram = [v for k, v in record["daemon"]["energy_j"].items() if k.startswith("DDR_")]
    assert len(dram) == 4 and all(v is not None and v > 0 for v in dram)
