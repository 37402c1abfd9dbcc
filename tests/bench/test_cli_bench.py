"""Tests of ``hdeem-watch bench`` as a real subprocess: JSON lines, table, errors, CPUs, daemon calls."""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zmq

SRC = Path(__file__).resolve().parents[2] / "src"
REQUIRED = ("kernel", "threads", "elements", "seconds", "lines_per_s", "dram_bytes_per_s", "stream_bytes_per_s")


def bench(*args: str, cpus: set[int] | None = None, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    """Run ``python -m hdeem_watch bench ARGS`` (optionally restricted to ``cpus``)."""
    env = {**os.environ, "PYTHONPATH": f"{SRC}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    env = {k: v for k, v in env.items() if not k.startswith("SLURM_")}

    def restrict() -> None:
        if cpus is not None:
            os.sched_setaffinity(0, cpus)

    return subprocess.run([sys.executable, "-m", "hdeem_watch", "bench", *args], capture_output=True,
                          text=True, env=env, timeout=timeout, preexec_fn=restrict)


@pytest.mark.slow
def test_json_lines_one_object_per_run() -> None:
    """--json prints one strict JSON object per run and line, with the contract's keys and values
    consistent with the DRAM model's traffic; nothing else on stdout."""
    threads = "1-2" if len(os.sched_getaffinity(0)) >= 2 else "1"
    proc = bench("--kernels", "read,addition,idle", "--threads", threads, "--elements", "65536",
                 "--repeat", "2", "--json")
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    n_threads = 2 if threads == "1-2" else 1
    assert len(lines) == 3 * n_threads
    records = [json.loads(line) for line in lines]
    assert [r["kernel"] for r in records] == ["read"] * n_threads + ["add"] * n_threads + ["idle"] * n_threads
    for record in records:
        assert all(key in record for key in REQUIRED)
        assert record["elements"] == 65536 and record["repeat"] == 2
        assert record["seconds"] > 0
        moved = (record["lines_read_per_pass"] + record["lines_written_per_pass"]) * 64 * 2
        assert record["dram_bytes_per_s"] == pytest.approx(moved / record["seconds"])
        # STREAM's convention: each array read or written once per element (add: 3 lines), no write-allocate
        stream_lines = {"read": 1, "add": 3, "idle": 0}[record["kernel"]]
        assert record["stream_bytes_per_s"] == pytest.approx(stream_lines * 8192 * 64 * 2 / record["seconds"])
        assert record["t_end_ns"] >= record["t_start_ns"]
        assert len(record["cpus"]) == record["threads"]
    add = records[n_threads]
    assert (add["lines_read_per_pass"], add["lines_written_per_pass"]) == (3 * 8192, 8192)
    assert add["lines_per_s"] == pytest.approx(8192 * 2 / add["seconds"])
    assert records[-1]["dram_bytes_per_s"] == 0


@pytest.mark.slow
def test_table_without_json() -> None:
    """Without --json the runs are printed as a table with a header and one row per run, in 80
    columns (issue 28: it wrapped)."""
    proc = bench("--kernels", "copy,triad", "--threads", "1", "--elements", "4096", "--repeat", "1")
    assert proc.returncode == 0, proc.stderr
    rows = proc.stdout.splitlines()
    assert rows[0].split()[:3] == ["kernel", "threads", "elements"]
    assert [row.split()[0] for row in rows[1:3]] == ["copy", "triad"]
    assert "DRAM GB/s" in rows[0] and "STREAM GB/s" in rows[0]
    assert rows[3].startswith("DRAM GB/s: what moves, write-allocate") and "STREAM GB/s: STREAM's" in rows[3]
    assert max(len(row) for row in rows) <= 80
    dram, stream = map(float, rows[1].split()[6:8])  # kernel threads elements repeat seconds Mlines/s DRAM STREAM
    # copy moves 3 lines per element (read a, write-allocate b, write b); STREAM counts 2
    assert dram == pytest.approx(1.5 * stream, abs=0.02)
    assert "last-level cache" in proc.stderr  # 64 KiB arrays: the LLC warning


@pytest.mark.parametrize(("args", "needle"), [
    (("--threads", "0"), "--threads"),
    (("--threads", "4-2"), "--threads"),
    (("--kernels", "stream"), "kernel 'stream'"),
    (("--elements", "abc"), "--elements"),
    (("--repeat", "0"), "--repeat"),
    (("--threads", "4096", "--elements", "64"), "CPUs are allowed"),
])
def test_bad_input_exits_2_with_one_line(args: tuple[str, ...], needle: str,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    """Bad input (bad thread spec, unknown kernel, bad sizes, too many threads) exits 2 with one
    line on stderr and nothing on stdout (in-process through the CLI entry point)."""
    from hdeem_watch.cli import main

    assert main(["bench", *args, "--json"]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert len(err.strip().splitlines()) == 1
    assert needle in err and "Traceback" not in err


@pytest.mark.slow
def test_impossible_size_exits_2_before_allocating() -> None:
    """An array size beyond the available memory exits 2 with one line (a real process: no OOM
    kill, no traceback)."""
    proc = bench("--elements", "1e15", "--kernels", "add", "--json")
    assert proc.returncode == 2 and proc.stdout == ""
    assert len(proc.stderr.strip().splitlines()) == 1
    assert "--elements 1000000000000000" in proc.stderr and "GiB" in proc.stderr


@pytest.mark.slow
def test_respects_the_cpus_it_was_given() -> None:
    """Started with an affinity of one CPU, the bench pins there and refuses two threads."""
    cpu = max(os.sched_getaffinity(0))
    proc = bench("--kernels", "read", "--threads", "1", "--elements", "8192", "--repeat", "1", "--json",
                 cpus={cpu})
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["cpus"] == [cpu]
    proc = bench("--kernels", "read", "--threads", "2", "--elements", "8192", "--json", cpus={cpu})
    assert proc.returncode == 2 and "only 1 CPUs" in proc.stderr


class FakeRouter:
    """A real ROUTER socket answering the control protocol, recording each request with its time."""

    def __init__(self, endpoint: str, fail_start_after: int | None = None, conflicts: int = 0,
                 shortest_s: float = 0.0) -> None:
        self.endpoint = endpoint
        self.shortest_s = shortest_s  # as the daemon's guard rail: a shorter window is not calibrated
        self.fail_start_after = fail_start_after
        self.conflicts = conflicts  # refuse this many run.start with "conflict" (another run open)
        self.requests: list[tuple[int, dict[str, Any]]] = []
        self._stop = threading.Event()
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()
        self._ready.wait(5)

    def _serve(self) -> None:
        ctx = zmq.Context.instance()
        sock = ctx.socket(zmq.ROUTER)
        sock.setsockopt(zmq.LINGER, 0)
        sock.bind(self.endpoint)
        self._ready.set()
        runs = 0
        while not self._stop.is_set():
            if not sock.poll(50):
                continue
            frames = sock.recv_multipart()
            request = json.loads(frames[-1])
            self.requests.append((time.time_ns(), request))
            op = request["op"]
            if op == "status":
                result: Any = {"node": "fake", "endpoints": {}, "source": {}, "channels": {}}
            elif op == "run.start" and self.conflicts > 0:
                self.conflicts -= 1
                reply = {"id": request["id"], "ok": False,
                         "error": {"code": "conflict", "message": "run 7 is in progress; stop it first"}}
                sock.send_multipart([*frames[:-1], json.dumps(reply).encode()])
                continue
            elif op == "run.start":
                runs += 1
                if self.fail_start_after is not None and runs > self.fail_start_after:
                    reply = {"id": request["id"], "ok": False,
                             "error": {"code": "busy", "message": "a run is already in progress"}}
                    sock.send_multipart([*frames[:-1], json.dumps(reply).encode()])
                    continue
                result = {"run_id": f"r{runs}"}
            elif op == "run.stop":
                result = {"run_id": request["args"]["run_id"], "energy_j": {"DDR_AB": 1.5}}
                if self.shortest_s:
                    window_s = (time.time_ns() - self.requests[-2][0]) / 1e9
                    result.update({"fit": None, "model_error": f"not calibrated: too short ({window_s:.2f} s)"}
                                  if window_s < self.shortest_s else {"fit": {"currents": {}}, "model_error": None})
            else:
                reply = {"id": request["id"], "ok": False, "error": {"code": "unknown-op", "message": op}}
                sock.send_multipart([*frames[:-1], json.dumps(reply).encode()])
                continue
            reply = {"id": request["id"], "ok": True, "result": result}
            sock.send_multipart([*frames[:-1], json.dumps(reply).encode()])
        sock.close(linger=0)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)


@pytest.fixture
def router(tmp_path: Path) -> Iterator[FakeRouter]:
    server = FakeRouter(f"ipc://{tmp_path / 'control.sock'}")
    yield server
    server.close()


@pytest.mark.slow
def test_announcements_bracket_each_run(router: FakeRouter) -> None:
    """With --daemon, the bench asks status once, then per run sends run.start (name, kernel,
    threads, elements, repeat, metadata) before its window and run.stop {run_id} after it."""
    proc = bench("--kernels", "copy,scale", "--threads", "1", "--elements", "16384", "--repeat", "2",
                 "--daemon", router.endpoint, "--json")
    assert proc.returncode == 0, proc.stderr
    records = [json.loads(line) for line in proc.stdout.splitlines()]
    ops = [r["op"] for _, r in router.requests]
    # whoami: may this user's runs be recorded? (this fake answers unknown-op, as an older daemon)
    assert ops == ["status", "whoami", "run.start", "run.stop", "run.start", "run.stop"]
    starts = [(t, r) for t, r in router.requests if r["op"] == "run.start"]
    stops = [(t, r) for t, r in router.requests if r["op"] == "run.stop"]
    for (t_start, start), (t_stop, stop), record in zip(starts, stops, records, strict=True):
        args = start["args"]
        assert {k: args[k] for k in ("kernel", "threads", "elements", "repeat")} == \
            {k: record[k] for k in ("kernel", "threads", "elements", "repeat")}
        assert args["name"] == f"{record['kernel']}-1t"
        assert isinstance(args["metadata"], dict) and args["metadata"]["tool"] == "hdeem-watch bench"
        assert stop["args"] == {"run_id": record["run_id"]}
        assert t_start <= record["t_start_ns"] <= record["t_end_ns"] <= t_stop
        assert record["daemon"]["energy_j"] == {"DDR_AB": 1.5}
    assert [r["run_id"] for r in records] == ["r1", "r2"]


@pytest.mark.slow
def test_unreachable_daemon_is_bad_input(tmp_path: Path) -> None:
    """--daemon pointing at nothing exits 2 with one line before running anything."""
    proc = bench("--kernels", "read", "--elements", "4096", "--daemon", f"ipc://{tmp_path}/none.sock",
                 "--timeout", "0.5", "--json")
    assert proc.returncode == 2 and proc.stdout == ""
    assert "--daemon" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1


@pytest.mark.slow
def test_progress_bar_on_a_terminal_only() -> None:
    """On a terminal stderr shows a progress bar (carriage-return updates ending at n/n); stdout
    keeps only the JSON lines. Without a terminal there is no bar."""
    import pty

    master, slave = pty.openpty()
    env = {k: v for k, v in os.environ.items() if not k.startswith("SLURM_")}
    env["PYTHONPATH"] = f"{SRC}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"
    try:
        proc = subprocess.run([sys.executable, "-m", "hdeem_watch", "bench", "--kernels", "read,copy", "--threads",
                               "1", "--elements", "4096", "--repeat", "1", "--json"], stdout=subprocess.PIPE,
                              stderr=slave, env=env, timeout=60, text=True)
        os.close(slave)
        chunks = []
        while True:
            try:
                data = os.read(master, 65536)
            except OSError:
                break
            if not data:
                break
            chunks.append(data)
    finally:
        os.close(master)
    assert proc.returncode == 0
    terminal = b"".join(chunks).decode(errors="replace")
    assert "\r[" in terminal and "0/2" in terminal and "2/2" in terminal
    assert len(proc.stdout.splitlines()) == 2
    plain = bench("--kernels", "read", "--threads", "1", "--elements", "4096", "--repeat", "1", "--json")
    assert "\r[" not in plain.stderr


@pytest.mark.slow
def test_daemon_failing_mid_sweep_warns_once_and_finishes(tmp_path: Path) -> None:
    """If the daemon refuses a run.start mid-sweep, the bench warns once on stderr, stops
    announcing, and still runs and reports every run (exit 0)."""
    server = FakeRouter(f"ipc://{tmp_path / 'control.sock'}", fail_start_after=1)
    try:
        proc = bench("--kernels", "read,copy,scale", "--threads", "1", "--elements", "8192", "--repeat", "1",
                     "--daemon", server.endpoint, "--json")
    finally:
        server.close()
    assert proc.returncode == 0, proc.stderr
    records = [json.loads(line) for line in proc.stdout.splitlines()]
    assert [r["kernel"] for r in records] == ["read", "copy", "scale"]
    assert records[0]["run_id"] == "r1" and "run_id" not in records[1] and "run_id" not in records[2]
    assert [r["op"] for _, r in server.requests] == ["status", "whoami", "run.start", "run.stop", "run.start"]
    warnings = [line for line in proc.stderr.splitlines() if "run.start failed" in line]
    assert len(warnings) == 1 and "busy" in warnings[0] and "not announced" in warnings[0]


@pytest.mark.slow
def test_not_an_endpoint_is_bad_input() -> None:
    """--daemon with something that is no ZeroMQ endpoint exits 2 with one line naming it (it used
    to end in a ZMQError traceback)."""
    proc = bench("--kernels", "read", "--elements", "4096", "--daemon", "nonsense", "--json")
    assert proc.returncode == 2 and proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "--daemon 'nonsense'" in lines[0] and "ipc://" in lines[0]


@pytest.mark.slow
def test_a_run_refused_while_another_is_open_is_retried(tmp_path: Path) -> None:
    """A run.start answered 'conflict' (another run open on the daemon) is asked again about every
    second; once the daemon accepts, the run is announced as usual and the exit code is 0."""
    server = FakeRouter(f"ipc://{tmp_path / 'control.sock'}", conflicts=2)
    try:
        proc = bench("--kernels", "read", "--threads", "1", "--elements", "8192", "--repeat", "1",
                     "--daemon", server.endpoint, "--wait", "30", "--json")
    finally:
        server.close()
    assert proc.returncode == 0, proc.stderr
    (record,) = [json.loads(line) for line in proc.stdout.splitlines()]
    assert record["run_id"] == "r1" and record["daemon"]["energy_j"] == {"DDR_AB": 1.5}
    starts = [t for t, r in server.requests if r["op"] == "run.start"]
    assert len(starts) == 3
    assert all(later - earlier >= 0.9e9 for earlier, later in itertools.pairwise(starts))
    waiting = [line for line in proc.stderr.splitlines() if "another run open" in line]
    assert len(waiting) == 1 and "waiting up to 30 s" in waiting[0]


@pytest.mark.slow
def test_a_run_still_refused_after_the_wait_exits_1(tmp_path: Path) -> None:
    """If the daemon still refuses after --wait seconds, the sweep stops there with one error line
    and exit code 1 (a batch script can tell), instead of finishing without energies."""
    server = FakeRouter(f"ipc://{tmp_path / 'control.sock'}", conflicts=1000)
    try:
        proc = bench("--kernels", "read,copy", "--threads", "1", "--elements", "8192", "--repeat", "1",
                     "--daemon", server.endpoint, "--wait", "1.5", "--json")
    finally:
        server.close()
    assert proc.returncode == 1 and proc.stdout == ""
    assert "Traceback" not in proc.stderr
    error = proc.stderr.strip().splitlines()[-1]
    assert error.startswith("hdeem-watch bench: error: ") and "still refused run.start for read-1t" in error
    assert "after waiting 1.5 s" in error and "run 7 is in progress" in error and "0 of 2 runs done" in error
    ops = [r["op"] for _, r in server.requests]
    assert ops[:2] == ["status", "whoami"] and set(ops[2:]) == {"run.start"} and 2 <= len(ops) - 2 <= 4


@pytest.mark.slow
def test_a_run_cut_short_by_a_slowed_probe_is_run_again(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    """A probe slowed 8x (another process had the core while the passes were timed, as under load)
    sizes the run far too short; the daemon does not calibrate it, so the bench runs it once more
    with the passes scaled by the time it missed, and that run is the one reported."""
    from hdeem_watch.bench import runner
    from hdeem_watch.cli import main

    real_probe = runner._probe
    monkeypatch.setattr(runner, "_probe", lambda probe, more: 8 * real_probe(probe, more))
    server = FakeRouter(f"ipc://{tmp_path / 'control.sock'}", shortest_s=0.25)
    try:
        code = main(["bench", "--kernels", "copy", "--threads", "1", "--elements", "262144", "--seconds", "0.5",
                     "--daemon", server.endpoint, "--json"])
    finally:
        server.close()
    out, err = capsys.readouterr()
    assert code == 0, err
    starts = [r["args"]["repeat"] for _, r in server.requests if r["op"] == "run.start"]
    # scaled by the time the first run missed (~8x here; less when the machine is busy during it too)
    assert len(starts) == 2 and starts[1] > 2 * starts[0], starts
    (record,) = [json.loads(line) for line in out.splitlines()]
    assert record["run_id"] == "r2" and record["repeat"] == starts[1] and record["seconds"] >= 0.25
    assert record["daemon"]["fit"] is not None
    assert "running it again with" in err and "not calibrated" not in err
