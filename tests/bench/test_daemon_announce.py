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


@pytest.mark.slow
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


@pytest.mark.slow
def test_default_runs_are_long_enough_for_the_daemon_to_fit_every_one(daemon: str) -> None:
    """Issue 28: with the defaults (runs sized by --seconds from a probe pass) every run of
    `bench --kernels read,assign,triad,idle --threads 2 --daemon EP` is fitted by the real sim
    daemon; before, all were refused as too short (2**25 elements x 10 passes: ~0.1 s). The sizing
    is the same for every kernel; these four span it: read only, write only, the BLAS kernel (its
    library loads before the probe) and idle (no passes). Two threads: through the workers' shared
    probe and start barriers (one thread is the same path with one)."""
    proc = subprocess.run([sys.executable, "-m", "hdeem_watch", "bench", "--kernels", "read,assign,triad,idle", "--threads", "2",
                           "--daemon", daemon, "--json"],
                          capture_output=True, text=True, timeout=600, env=_env())
    assert proc.returncode == 0, proc.stderr
    records = [json.loads(line) for line in proc.stdout.splitlines()]
    assert [r["kernel"] for r in records] == ["read", "assign", "triad", "idle"]
    for record in records:
        run = record["daemon"]
        assert run["fit"] is not None, (record["kernel"], record["threads"], record["seconds"], run["model_error"])
        assert run["repeat"] == record["repeat"] >= 1 and record["seconds"] >= 1.0
    assert "not calibrated" not in proc.stderr


@pytest.mark.slow
def test_too_short_runs_get_one_summary_warning_with_the_fix(daemon: str) -> None:
    """Runs the daemon refuses (here exact --repeat counts far below a second) get one summary
    warning naming how many and the fix, not one warning per run."""
    proc = subprocess.run([sys.executable, "-m", "hdeem_watch", "bench", "--kernels", "read,copy,idle", "--threads",
                           "1", "--elements", "65536", "--repeat", "2", "--daemon", daemon],
                          capture_output=True, text=True, timeout=120, env=_env())
    assert proc.returncode == 0, proc.stderr
    warnings = [line for line in proc.stderr.splitlines() if "not calibrated" in line]
    assert len(warnings) == 1, proc.stderr
    assert "3 of 3 runs were not calibrated" in warnings[0] and "drop --repeat" in warnings[0]
    assert "samples of" not in proc.stderr.replace(warnings[0], "")


@pytest.mark.slow
def test_ctrl_c_aborts_the_announced_run_and_the_daemon_takes_the_next_at_once(daemon: str) -> None:
    """Issue 28: Ctrl-C in `bench --daemon` aborts the run it announced (state aborted) before it
    exits 130; the next run.start is accepted at once (before: refused, 'run rN is in progress')."""
    bench = subprocess.Popen([sys.executable, "-m", "hdeem_watch", "bench", "--kernels", "read", "--threads", "1",
                              "--elements", "65536", "--seconds", "30", "--daemon", daemon],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env())
    with ControlClient(daemon, timeout_s=5.0) as client:
        deadline = time.monotonic() + 60
        while (running := client.call("status")["run"]) is None:
            assert time.monotonic() < deadline and bench.poll() is None, "the bench never announced its run"
            time.sleep(0.1)
        bench.send_signal(signal.SIGINT)
        _out, err = bench.communicate(timeout=10)
        assert bench.returncode == 130, err
        assert f"run {running['run_id']} aborted" in err and "Traceback" not in err
        other = client.call("run.start", {"kernel": "copy", "name": "next"})
        client.call("run.stop", {"run_id": other["run_id"]})
        (stored,) = [r for r in client.call("runs.list", {"limit": 10})["runs"] if r["run_id"] == running["run_id"]]
    assert stored["state"] == "aborted"


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "hdeem_watch", *args], capture_output=True, text=True,
                          timeout=60, env=_env())


@pytest.mark.slow
def test_run_list_and_run_stop_abort_against_a_real_daemon(daemon: str) -> None:
    """Issue 28: `run stop --abort` ends the run in progress (a bench killed with -9 leaves one
    open) without calibrating; `run list` shows it aborted beside a calibrated one; with no run in
    progress `run stop` says so (exit 1)."""
    with ControlClient(daemon, timeout_s=5.0) as client:
        left_open = client.call("run.start", {"kernel": "triad", "name": "killed-bench"})["run_id"]
    stopped = _cli("run", "stop", "--abort", "--connect", daemon)
    assert stopped.returncode == 0, stopped.stderr
    assert stopped.stdout.startswith(f"run {left_open} (killed-bench) aborted (stored, not calibrated)")
    again = _cli("run", "stop", "--connect", daemon)
    assert again.returncode == 1 and "no run is in progress" in again.stderr and "Traceback" not in again.stderr
    bench = _cli("bench", "--kernels", "read", "--seconds", "1.5", "--daemon", daemon, "--json")
    assert bench.returncode == 0, bench.stderr
    listed = _cli("run", "list", "--connect", daemon)
    assert listed.returncode == 0, listed.stderr
    lines = listed.stdout.splitlines()
    assert lines[0].split()[:3] == ["run", "name", "state"] and max(map(len, lines)) <= 80
    rows = {line.split()[0]: line for line in lines[1:]}
    assert "aborted" in rows[left_open] and rows[left_open].endswith("no (aborted)")
    (bench_run,) = [json.loads(line)["run_id"] for line in bench.stdout.splitlines()]
    assert rows[bench_run].endswith("yes"), listed.stdout


@pytest.mark.slow
@pytest.mark.parametrize("endpoint", ["garbage", "tcp://nohost", "udp://x:1"])
def test_run_commands_refuse_a_bad_endpoint_in_one_line(endpoint: str) -> None:
    """A --connect that is no control endpoint is bad input: one line naming it, exit 2."""
    proc = _cli("run", "list", "--connect", endpoint)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines() == [f"hdeem-watch: error: --connect {endpoint!r}: expected a control "
                                                "endpoint such as tcp://node7:5591 or ipc:///run/hdeem-watch/control.sock"]
