"""The SLURM hooks' failure behaviour, run as slurmd runs them (``sh prolog.sh`` with no search
path): whatever goes wrong they exit 0, within a bounded time, and say why on syslog.

Syslog is a real datagram socket the test binds (the hooks' ``HDEEM_WATCH_LOG_SOCKET``, which
``logger -u`` and Python's ``SysLogHandler`` write to as they would to /dev/log).
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

#: Every test runs the hooks as processes.
pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[2]
HOOKS = REPO / "daemon" / "slurm"


class Syslog:
    """A syslog socket: the lines written to it."""

    def __init__(self, path: Path) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.sock.settimeout(0.2)
        self.path = path

    def lines(self) -> list[str]:
        found = []
        while True:
            try:
                found.append(self.sock.recv(65536).decode(errors="replace"))
            except TimeoutError:
                return found


@pytest.fixture
def syslog(tmp_path: Path) -> Iterator[Syslog]:
    log = Syslog(tmp_path / "log.sock")
    yield log
    log.sock.close()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _hook(hook: str, tmp_path: Path, syslog: Syslog, **settings: str) -> tuple[subprocess.CompletedProcess[str], float]:
    """Run a hook as slurmd does (root's Prolog/Epilog environment, no PATH); return it and its wall time."""
    config = tmp_path / "daemon.toml"
    if not config.exists():
        config.write_text(f'control = "tcp://127.0.0.1:{_free_port()}"\nstate_dir = "{tmp_path}/state"\n')
    env = {"SLURM_JOB_ID": "5", "SLURM_JOB_USER": "alice", "SLURM_JOB_UID": "1000", "SLURMD_NODENAME": "n1",
           "SLURM_NODELIST": "n1", "SLURM_SCRIPT_CONTEXT": f"{hook}_slurmd", "SLURM_JOB_EXIT_CODE": "0",
           "HDEEM_WATCH_HOOK_CONF": str(tmp_path / "absent.env"), "HDEEM_WATCH_LOG_SOCKET": str(syslog.path),
           "HDEEM_WATCH_CONFIG": str(config), "PYTHONPATH": str(REPO / "src"), **settings}
    began = time.monotonic()
    proc = subprocess.run(["/bin/sh", str(HOOKS / f"{hook}.sh")], env=env, capture_output=True, text=True,
                          timeout=120, check=False)
    return proc, time.monotonic() - began


@pytest.mark.parametrize(("python", "why"), [("/nonexistent/bin/python3", "does not exist or is not executable"),
                                             ("python3", "is not an absolute path"), ("", "is not an absolute path")])
def test_no_interpreter_exits_0_and_says_so_on_syslog(tmp_path: Path, syslog: Syslog, python: str, why: str) -> None:
    """A Prolog whose interpreter is missing or not given by absolute path exits 0 (the node is not
    drained) and logs one line naming the job and the fix, tagged hdeem-watch-slurm."""
    proc, _seconds = _hook("prolog", tmp_path, syslog, HDEEM_WATCH_PYTHON=python)
    assert proc.returncode == 0
    lines = syslog.lines()
    assert len(lines) == 1 and "hdeem-watch-slurm" in lines[0] and "prolog job 5" in lines[0] and why in lines[0]
    assert "HDEEM_WATCH_PYTHON" in lines[0]


def test_a_daemon_that_does_not_answer_costs_bounded_time(tmp_path: Path, syslog: Syslog) -> None:
    """The daemon's TCP control port is silent: the Prolog gives up after its call timeout and exits
    0, the Epilog too and keeps the stop for the next hook; each takes a few seconds at most."""
    python = {"HDEEM_WATCH_PYTHON": sys.executable, "HDEEM_WATCH_HOOK_CALL_TIMEOUT_S": "1"}
    prolog, prolog_s = _hook("prolog", tmp_path, syslog, **python)
    assert prolog.returncode == 0 and prolog_s < 8, prolog.stderr
    assert any("prolog job 5: no daemon answers" in line for line in syslog.lines())
    (tmp_path / "state" / "slurm-hooks" / "job-5.json").unlink()  # as if the Prolog had opened the job
    epilog, epilog_s = _hook("epilog", tmp_path, syslog, **python)
    assert epilog.returncode == 0 and epilog_s < 8, epilog.stderr
    assert any("epilog job 5" in line and "kept" in line for line in syslog.lines())
    stop = json.loads((tmp_path / "state" / "slurm-hooks" / "stop-5.json").read_text())
    assert stop["job_id"] == "5" and stop["exit_code"] == "0" and stop["ended_ns"] > 0


def test_a_hung_hook_is_cut_by_its_timeout(tmp_path: Path, syslog: Syslog) -> None:
    """An interpreter that hangs is killed after HDEEM_WATCH_HOOK_TIMEOUT_S; the hook exits 0 and
    says so."""
    hung = tmp_path / "python3"
    hung.write_text("#!/bin/sh\nsleep 60\n")
    hung.chmod(0o755)
    proc, seconds = _hook("epilog", tmp_path, syslog, HDEEM_WATCH_PYTHON=str(hung), HDEEM_WATCH_HOOK_TIMEOUT_S="1")
    assert proc.returncode == 0 and seconds < 5
    assert any("timed out after 1 s" in line for line in syslog.lines())


def test_an_hdeem_daemon_is_not_started_unless_asked(tmp_path: Path, syslog: Syslog) -> None:
    """With HDEEM_WATCH_START_DAEMON=1 but a daemon config on the hdeem source, the Prolog does not
    start a daemon (it would share the node's HDEEM with its users) unless HDEEM_WATCH_START_HDEEM=1."""
    (tmp_path / "daemon.toml").write_text(f'source = "hdeem"\ncontrol = "ipc://{tmp_path}/c.sock"\n'
                                          f'state_dir = "{tmp_path}/state"\n')
    proc, _seconds = _hook("prolog", tmp_path, syslog, HDEEM_WATCH_PYTHON=sys.executable, HDEEM_WATCH_START_DAEMON="1")
    assert proc.returncode == 0
    record = json.loads((tmp_path / "state" / "slurm-hooks" / "job-5.json").read_text())
    assert record["daemon"].startswith("not started: its source is hdeem")
    assert not (tmp_path / "state" / "slurm-hooks" / "daemon.json").exists()


def test_a_hung_daemon_gets_no_twin_and_its_missed_stop_comes_later(tmp_path: Path, syslog: Syslog) -> None:
    """A real daemon stops answering (SIGSTOP) during a job: the Epilog keeps the stop; a Prolog with
    HDEEM_WATCH_START_DAEMON=1 tries to start one with the same config, which refuses to run beside
    the hung one (its state directory is locked), so there is never a second daemon; once the daemon
    answers again the next hook delivers the stop, and the record says it came late."""
    import signal

    from hdeem_watch.wire.client import ControlClient

    control, daemon = _start_daemon(tmp_path)
    python = {"HDEEM_WATCH_PYTHON": sys.executable, "HDEEM_WATCH_HOOK_CALL_TIMEOUT_S": "1"}
    try:
        prolog, _s = _hook("prolog", tmp_path, syslog, **python)
        hooks = tmp_path / "state" / "slurm-hooks"
        assert json.loads((hooks / "job-5.json").read_text())["job_start"] == "ok", prolog.stderr
        daemon.send_signal(signal.SIGSTOP)
        epilog, epilog_s = _hook("epilog", tmp_path, syslog, **python)
        assert epilog.returncode == 0 and epilog_s < 8 and (hooks / "stop-5.json").exists()
        twin, _s = _hook("prolog", tmp_path, syslog, SLURM_JOB_ID="6", HDEEM_WATCH_START_DAEMON="1", **python)
        assert twin.returncode == 0
        assert json.loads((hooks / "job-6.json").read_text())["daemon"].startswith("not started: it exited with 2")
        assert not (hooks / "daemon.json").exists()
        daemon.send_signal(signal.SIGCONT)
        time.sleep(1.5)
        later, _s = _hook("prolog", tmp_path, syslog, SLURM_JOB_ID="7", **python)
        assert later.returncode == 0 and not (hooks / "stop-5.json").exists()
        with ControlClient(control, timeout_s=5.0) as client:
            record = client.call("job.get", {"job_id": "5"})
        assert record["state"] == "done" and record["late_stop_s"] >= 1.0 and "late stop" in record["status"]
    finally:
        daemon.send_signal(signal.SIGCONT)
        daemon.terminate()
        daemon.wait(timeout=20)


def _start_daemon(tmp_path: Path) -> tuple[str, subprocess.Popen[bytes]]:
    """A sim daemon with the config file the hooks read (``tmp_path/daemon.toml``), answering."""
    from hdeem_watch.wire.client import ControlClient, DaemonUnreachable

    control = f"ipc://{tmp_path}/run/c.sock"
    (tmp_path / "daemon.toml").write_text(f'source = "sim"\ncontrol = "{control}"\npub = "ipc://{tmp_path}/run/p.sock"\n'
                                          f'state_dir = "{tmp_path}/state"\n')
    env = {"PYTHONPATH": str(REPO / "src"), "PATH": "/usr/bin:/bin"}
    daemon = subprocess.Popen([sys.executable, "-m", "hdeem_watch", "daemon", "--config", str(tmp_path / "daemon.toml")],
                              env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    with ControlClient(control, timeout_s=1.0) as client:
        deadline = time.monotonic() + 30
        while True:
            try:
                client.call("ping")
                return control, daemon
            except DaemonUnreachable:
                assert time.monotonic() < deadline and daemon.poll() is None, "the daemon did not start"
                time.sleep(0.1)


def test_the_prolog_measures_a_baseline_only_when_asked(tmp_path: Path, syslog: Syslog) -> None:
    """HDEEM_WATCH_PROLOG_BASELINE_S=1: the Prolog measures an idle baseline (the job starts that
    much later), then opens the job; the job's above-baseline energy then has a baseline."""
    from hdeem_watch.wire.client import ControlClient

    control, daemon = _start_daemon(tmp_path)
    python = {"HDEEM_WATCH_PYTHON": sys.executable}
    try:
        prolog, prolog_s = _hook("prolog", tmp_path, syslog, HDEEM_WATCH_PROLOG_BASELINE_S="1", **python)
        record = json.loads((tmp_path / "state" / "slurm-hooks" / "job-5.json").read_text())
        assert record["baseline"] == "measured" and record["job_start"] == "ok", prolog.stderr
        assert prolog_s >= 1.0
        with ControlClient(control, timeout_s=5.0) as client:
            baselines = client.call("baseline.get")["channels"]
            assert baselines["DDR_AB"]["origin"] == "measured"
            epilog, _s = _hook("epilog", tmp_path, syslog, **python)
            assert epilog.returncode == 0
            job = client.call("job.get", {"job_id": "5"})
        assert job["state"] == "done" and job["baseline_status"] == "ok"
        assert job["dram_above_baseline_j"] == job["dram_above_baseline_j"]  # a number, not NaN
    finally:
        daemon.terminate()
        daemon.wait(timeout=20)


def test_the_hooks_log_is_bounded(tmp_path: Path) -> None:
    """jobs.jsonl is rotated to jobs.jsonl.1 beyond MAX_LOG_BYTES: at most twice that on disk."""
    from hdeem_watch.slurm import hooks

    log = tmp_path / "jobs.jsonl"
    line = {"event": "prolog", "job_id": "1", "pad": "x" * 1000}
    for _ in range(3 * hooks.MAX_LOG_BYTES // 1000):
        hooks._append_bounded(log, line)
    sizes = [p.stat().st_size for p in sorted(tmp_path.glob("jobs.jsonl*"))]
    assert len(sizes) == 2 and all(size <= hooks.MAX_LOG_BYTES + 1100 for size in sizes)
    assert json.loads(log.read_text().splitlines()[-1]) == line


def _hook_env(tmp_path: Path, syslog: Syslog, **fields: str) -> dict[str, str]:
    """A Prolog/Epilog environment for calling the hooks in this process (the daemon's config file
    ``tmp_path/daemon.toml``)."""
    env = {"SLURM_JOB_USER": "alice", "SLURM_JOB_UID": "1000", "SLURMD_NODENAME": "n1", "SLURM_NODELIST": "n1",
           "SLURM_JOB_EXIT_CODE": "0", "HDEEM_WATCH_LOG_SOCKET": str(syslog.path),
           "HDEEM_WATCH_CONFIG": str(tmp_path / "daemon.toml"), "HDEEM_WATCH_HOOK_CALL_TIMEOUT_S": "10"}
    env.update(fields)
    return {k: v for k, v in env.items() if v is not None}


@pytest.mark.slow
def test_an_empty_or_unset_job_id_opens_nothing_and_says_why(tmp_path: Path, syslog: Syslog) -> None:
    """SLURM_JOB_ID empty (the shell hook, as slurmd runs it), unset, or no job id at all (100 KB):
    the hooks exit 0, open and close nothing in the daemon (once: a job named ``"unknown"`` every
    such hook shared) and log why."""
    from hdeem_watch.slurm import hooks
    from hdeem_watch.wire.client import ControlClient

    control, daemon = _start_daemon(tmp_path)
    try:
        proc, _s = _hook("prolog", tmp_path, syslog, SLURM_JOB_ID="", HDEEM_WATCH_PYTHON=sys.executable)
        assert proc.returncode == 0, proc.stderr
        assert any("SLURM_JOB_ID is empty or unset: no job window opened" in line for line in syslog.lines())
        for hook in (hooks.prolog, hooks.epilog):
            assert hook(_hook_env(tmp_path, syslog))["job_id"] is None
            assert any("SLURM_JOB_ID is empty or unset" in line for line in syslog.lines())
            began = time.monotonic()
            record = hook(_hook_env(tmp_path, syslog, SLURM_JOB_ID="7" * 100_000))
            assert record["job_id"] is None and time.monotonic() - began < 1.0
            said = [line for line in syslog.lines() if "is not a SLURM job id" in line]
            assert said and all(len(line) < 400 for line in said)
        with ControlClient(control, timeout_s=5.0) as client:
            assert client.call("job.list")["jobs"] == [] and client.call("status")["jobs"] == []
        assert [p.name for p in (tmp_path / "state" / "slurm-hooks").glob("job-*")] == []
    finally:
        daemon.terminate()
        daemon.wait(timeout=20)


@pytest.mark.slow
def test_a_retried_prolog_and_a_refused_one_return_at_once(tmp_path: Path, syslog: Syslog) -> None:
    """A Prolog run twice for one job (slurmd retries) gets the open job's record again in well
    under a second (once: 10 s, the call's timeout); one whose uid is out of range is refused by the
    daemon at once too (once: its error reply had no id, the client waited 10 s)."""
    from hdeem_watch.slurm import hooks
    from hdeem_watch.wire.client import ControlClient

    control, daemon = _start_daemon(tmp_path)
    umask = os.umask(0o022)  # slurmd's, usually: the hooks' files are private all the same
    try:
        env = _hook_env(tmp_path, syslog, SLURM_JOB_ID="555")
        assert hooks.prolog(env)["job_start"] == "ok"
        began = time.monotonic()
        again = hooks.prolog(env)
        retried_s = time.monotonic() - began
        assert again["job_start"] == "ok" and retried_s < 1.0, (again, retried_s)
        began = time.monotonic()
        refused = hooks.prolog(_hook_env(tmp_path, syslog, SLURM_JOB_ID="556", SLURM_JOB_UID="9" * 20))
        assert refused["job_start"].startswith("bad-args") and time.monotonic() - began < 1.0, refused
        with ControlClient(control, timeout_s=5.0) as client:
            assert [j["job_id"] for j in client.call("status")["jobs"]] == ["555"]
        hook_files = {p.name: p.stat().st_mode & 0o777 for p in (tmp_path / "state" / "slurm-hooks").iterdir()}
        assert hook_files["job-555.json"] == 0o600 and hook_files["jobs.jsonl"] == 0o600, hook_files
    finally:
        os.umask(umask)
        daemon.terminate()
        daemon.wait(timeout=20)
