"""``hdeem-watch jobs``: which daemons it asks, ``--since``, and a node that does not answer."""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from hdeem_watch.cli.jobs import Target, parse_since, query, table, targets, total_line
from hdeem_watch.errors import InputError

SRC = Path(__file__).resolve().parents[1] / "src"


def _args(**given: object) -> argparse.Namespace:
    values: dict[str, object] = {"connect": [], "slurm": False, "port": None}
    values.update(given)
    return argparse.Namespace(**values)


def test_since_takes_a_time_ago_or_an_iso_time() -> None:
    """--since 30min/2h/1d counts back from now; an ISO time is taken as it is; anything else is a
    one-line error naming the option."""
    now = 1_800_000_000 * 10**9
    assert parse_since("30min", now) == now - 1800 * 10**9
    assert parse_since("1d", now) == now - 86400 * 10**9
    assert parse_since("2026-11-25T14:00:00+00:00") == 1_795_615_200 * 10**9
    with pytest.raises(InputError, match="--since 'yesterday'"):
        parse_since("yesterday")


def test_targets_inside_an_allocation_ask_every_node() -> None:
    """Inside an allocation every node is asked on the control port, this node through its local
    endpoint; --connect names daemons explicitly; --slurm outside an allocation is bad input."""
    env = {"SLURM_JOB_NODELIST": "c[1-3]", "SLURMD_NODENAME": "c2", "HDEEM_WATCH_CONTROL": "ipc:///x/c.sock",
           "HDEEM_WATCH_CONTROL_PORT": "7411"}
    assert targets(_args(), env) == [Target("c1", "tcp://c1:7411"), Target("c2", "ipc:///x/c.sock"),
                                     Target("c3", "tcp://c3:7411")]
    assert targets(_args(connect=["tcp://n9:5591"]), env) == [Target("n9:5591", "tcp://n9:5591")]
    assert [t.endpoint for t in targets(_args(port=9), {"SLURM_JOB_NODELIST": "z1"})] == ["tcp://z1:9"]
    assert [t.endpoint for t in targets(_args(nodes="q[1-2]"), {})] == ["tcp://q1:5591", "tcp://q2:5591"]
    with pytest.raises(InputError, match="--slurm: no SLURM allocation"):
        targets(_args(slurm=True), {"HDEEM_WATCH_CONTROL": "ipc:///x/c.sock"})
    with pytest.raises(InputError, match="--connect"):
        targets(_args(connect=["node7:5591"]), {})


@pytest.mark.slow
def test_a_node_that_does_not_answer_is_a_line_not_a_hang(tmp_path: Path) -> None:
    """Nodes are asked in parallel with a bounded timeout: two dead ones cost one timeout, and each
    is a line saying so; the command exits 1."""
    dead = [Target("a", f"ipc://{tmp_path}/a.sock"), Target("b", "tcp://127.0.0.1:9")]
    began = time.monotonic()
    answers = query(dead, "job.list", {}, timeout_s=0.5)
    assert time.monotonic() - began < 1.5
    assert [a["ok"] for a in answers] == [False, False]
    lines = table(answers)
    assert lines[1].startswith("a  ") and "unreachable" in lines[1] and "unreachable" in lines[2]
    proc = subprocess.run([sys.executable, "-m", "hdeem_watch", "jobs", "--connect", "tcp://127.0.0.1:9",
                           "--timeout", "0.3"], capture_output=True, text=True, timeout=30,
                          env={"PYTHONPATH": str(SRC), "PATH": "/usr/bin:/bin"})
    assert proc.returncode == 1 and "unreachable" in proc.stdout, proc.stderr
    bad = subprocess.run([sys.executable, "-m", "hdeem_watch", "jobs", "--job", "1 2"], capture_output=True,
                         text=True, timeout=30, env={"PYTHONPATH": str(SRC), "PATH": "/usr/bin:/bin"})
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "--job" in bad.stderr


def test_one_job_over_several_nodes_has_a_total_only_when_every_node_answered() -> None:
    """--job over an allocation: the DRAM energies of the nodes add up; a node missing makes the
    total unknown (–), never a partial sum passed off as the job's."""
    def node(name: str, energy: float | None) -> dict[str, object]:
        if energy is None:
            return {"node": name, "ok": False, "error": "unreachable: no reply within 3 s"}
        return {"node": name, "ok": True, "jobs": [{"job_id": "9", "state": "done", "dram_energy_j": energy}]}

    assert total_line([node("a", 1.5)]) is None
    assert total_line([node("a", 1.5), node("b", 2.25)]).split()[:2] == ["total", "3.8"]  # type: ignore[union-attr]
    partial = total_line([node("a", 1.5), node("b", None)])
    assert partial is not None and "–" in partial and "1 of 2 nodes missing" in partial


def test_a_curve_daemon_answers_jobs_given_its_key(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                   capsys: pytest.CaptureFixture[str], serve_control: Any) -> None:
    """``jobs --connect tcp://… --server-key FILE`` reads a CURVE daemon's jobs; without the key the
    node's line says the daemon requires CURVE (exit 1), at once rather than after the timeout."""
    import zmq

    from hdeem_watch.cli import main
    from hdeem_watch.daemon.shell.control import ControlServer
    from hdeem_watch.daemon.shell.security import CurveServer
    from hdeem_watch.wire.keys import generate_keys

    for name in ("HDEEM_WATCH_SERVER_KEY", "HDEEM_WATCH_CLIENT_KEY", "XDG_CONFIG_HOME"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("HDEEM_WATCH_CONFIG", str(tmp_path / "absent.toml"))
    monkeypatch.setenv("HOME", str(tmp_path))
    context = zmq.Context()  # its own: the ZAP handler binds inproc://zeromq.zap.01 once per context
    public, secret = generate_keys(tmp_path / "server", "server")
    curve = CurveServer(context, str(secret), None)
    job = {"job_id": "77", "node": "c1", "user": "alice", "state": "running", "duration_s": 12.0,
           "energy_j": {"DDR_AB": 30.0}, "dram_energy_j": 30.0}
    server = ControlServer(context, "tcp://127.0.0.1:0", {"job.get": lambda args: job}, secure=curve.apply)
    try:
        with serve_control(server):
            assert main(["jobs", "--connect", server.endpoint, "--job", "77", "--server-key", str(public),
                         "--json"]) == 0
            assert '"job_id":"77"' in capsys.readouterr().out.replace(" ", "")
            started = time.monotonic()
            assert main(["jobs", "--connect", server.endpoint, "--job", "77", "--timeout", "10"]) == 1
            assert "requires CURVE" in capsys.readouterr().out
            assert time.monotonic() - started < 5
    finally:
        server.close()
        curve.close()
        context.term()


def test_the_table_fits_80_columns_with_a_peak_column_and_says_when_a_node_has_no_jobs() -> None:
    """Issue 28: the table was ~130 columns without the peak power the README promises, and a node
    without jobs printed nothing under the header."""
    job = {"job_id": "4242", "user": "alice", "state": "running", "t_start_ns": 1_795_000_000 * 10**9,
           "duration_s": 3723.0, "dram_energy_j": 1234.5, "dram_above_baseline_j": 234.5, "measured_s": 100.0,
           "peak_power_w": {"DDR_AB": 6.25, "DDR_CD": 7.5, "BLADE": 300.0}, "status": "ok"}
    lines = table([{"node": "node7", "ok": True, "jobs": [job], "op": "job.list"},
                   {"node": "node8", "ok": True, "jobs": [], "op": "job.list"}])
    assert max(len(line) for line in lines) <= 80
    assert lines[0].rstrip().endswith("mean W peak W")
    row = lines[1].split()
    assert row[:3] == ["node7", "4242", "alice"]
    assert row[-2:] == ["12.3", "7.5"]  # mean 1234.5 J / 100 s; peak: the highest DRAM pair, not BLADE
    assert lines[2].strip() == "running: ok"
    assert lines[3] == "node8     (no jobs on this node)"


def test_an_unknown_host_is_said_at_once() -> None:
    """Issue 28: an unknown host was reported as "no reply within 10 s" after the timeout."""
    began = time.monotonic()
    (answer,) = query([Target("x", "tcp://no-such-host.invalid:5591")], "job.list", {}, timeout_s=10.0)
    assert time.monotonic() - began < 5.0
    assert not answer["ok"] and answer["error"].startswith("unknown host 'no-such-host.invalid'")


@pytest.mark.slow
def test_ctrl_c_ends_jobs_within_a_second() -> None:
    """Issue 28: `jobs --timeout 20` against a daemon that does not answer exited 19 s after Ctrl-C
    (the thread pool was waited for); now within a second, exit 130."""
    proc = subprocess.Popen([sys.executable, "-m", "hdeem_watch", "jobs", "--connect", "tcp://127.0.0.1:9",
                             "--timeout", "20"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env={"PYTHONPATH": str(SRC), "PATH": "/usr/bin:/bin"})
    time.sleep(2.0)  # importing and asking
    began = time.monotonic()
    proc.send_signal(signal.SIGINT)
    proc.communicate(timeout=10)
    assert proc.returncode == 130 and time.monotonic() - began <= 1.0
