"""The SLURM hooks' failure behaviour, run as slurmd runs them (``sh prolog.sh`` with no search
path): whatever goes wrong they exit 0, within a bounded time, and say why on syslog.

Syslog is a real datagram socket the test binds (the hooks' ``HDEEM_WATCH_LOG_SOCKET``, which
``logger -u`` and Python's ``SysLogHandler`` write to as they would to /dev/log).
"""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

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
