"""The demo's processes and files: no orphaned daemon after kill -9, the log kept where it says,
run counts of this session, and the schedule making room for the TUI's ``s`` and ``b`` keys."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import psutil
import pytest

from hdeem_watch.demo.daemon import RUNTIME_PREFIX, sweep_orphaned_runtime_dirs
from hdeem_watch.demo.schedule import DemoSchedule, ScheduleEvent
from hdeem_watch.wire.client import ControlClient


def _daemon_children(pid: int, timeout_s: float = 30.0) -> list[psutil.Process]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        found = [p for p in psutil.Process(pid).children(recursive=True) if "daemon" in " ".join(p.cmdline())]
        if found:
            return found
        time.sleep(0.2)
    raise AssertionError("the demo started no daemon subprocess")


@pytest.mark.slow
def test_kill_9_of_the_demo_takes_its_daemon_along_and_the_next_demo_sweeps_the_directory() -> None:
    """kill -9 of ``hdeem-watch demo`` left the daemon running (orphaned) and its temporary directory
    behind; now the daemon gets SIGTERM from the kernel (PR_SET_PDEATHSIG) and exits, and the
    directory, whose owner is gone, is removed by the next demo's sweep.

    The demo gets a private temporary directory (``TMPDIR``, short enough for its ipc sockets), so
    the directories counted here are its own while other demos run beside it on other workers."""
    root = Path(tempfile.mkdtemp(prefix="hw-k9-"))
    demo = subprocess.Popen([sys.executable, "-m", "hdeem_watch", "demo", "--headless"],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                            env={**os.environ, "TMPDIR": str(root)})
    try:
        daemons = _daemon_children(demo.pid)
        assert demo.stdout is not None
        for line in demo.stdout:  # the daemon answers: the demo is past its start-up
            if line.startswith("demo: daemon at"):
                break
        runtime = set(root.glob(RUNTIME_PREFIX + "*"))
        demo.send_signal(signal.SIGKILL)
        demo.wait(10)
        _, alive = psutil.wait_procs(daemons, timeout=15)
        assert not alive, f"daemon pids {[p.pid for p in alive]} outlived the demo"
        assert runtime and all(path.exists() for path in runtime)
        removed = sweep_orphaned_runtime_dirs(root)
        assert runtime <= set(removed) and not any(path.exists() for path in runtime)
    finally:
        if demo.poll() is None:
            demo.kill()
        for p in psutil.process_iter():
            try:
                if p.ppid() == 1 and str(root) in " ".join(p.cmdline()):
                    p.kill()
            except psutil.Error:
                pass
        shutil.rmtree(root, ignore_errors=True)


@pytest.mark.slow
def test_sweep_leaves_live_and_unclaimed_directories_alone(tmp_path: Path) -> None:
    """Only a directory whose owner.pid names a dead process is removed."""
    live, dead, unclaimed = (tmp_path / f"{RUNTIME_PREFIX}{n}" for n in ("live", "dead", "new"))
    for path in (live, dead, unclaimed):
        path.mkdir()
    (live / "owner.pid").write_text(f"{os.getpid()}\n")
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    (dead / "owner.pid").write_text(gone.stdout)
    assert sweep_orphaned_runtime_dirs(tmp_path) == [dead]
    assert live.exists() and unclaimed.exists() and not dead.exists()


@pytest.mark.slow
def test_the_log_is_kept_where_it_is_printed_and_counts_are_this_sessions(tmp_path: Path) -> None:
    """With --state-dir the daemon log is kept there and printed; without it no path is printed (it
    used to print one and then delete it). A second demo on the same state directory sums up the
    stored runs in one line instead of replaying them, and its closing line counts its own runs."""
    state = tmp_path / "state"
    outputs = []
    for _ in range(2):
        done = subprocess.run(
            [sys.executable, "-m", "hdeem_watch", "demo", "--headless", "--duration", "4", "--speed", "4",
             "--state-dir", str(state)],
            capture_output=True, text=True, timeout=120, env={**os.environ, "COLUMNS": "200"},
        )  # fmt: skip
        assert done.returncode == 0, done.stderr
        outputs.append(done.stdout)
    log = state / "daemon.log"
    assert f"daemon log: {log}" in outputs[0] and log.stat().st_size > 0
    first_runs = [line for line in outputs[0].splitlines() if line.startswith("run ")]
    second = outputs[1].splitlines()
    assert any(line.startswith("runs   ") and "earlier run" in line for line in second), outputs[1]
    closing = next(line for line in second if line.startswith("demo: done after"))
    session_runs = int(closing.split(",")[1].split()[0])
    second_runs = [line for line in second if line.startswith("run ")]
    assert abs(session_runs - len(second_runs)) <= 1, (closing, len(second_runs))
    assert session_runs < len(first_runs) + len(second_runs)
    plain = subprocess.run([sys.executable, "-m", "hdeem_watch", "demo", "--headless", "--duration", "2"],
                           capture_output=True, text=True, timeout=120)
    assert plain.returncode == 0 and "daemon log" not in plain.stdout


@pytest.mark.slow
def test_the_schedule_pauses_after_a_run_stopped_from_outside_so_b_can_measure(sim_daemon) -> None:  # type: ignore[no-untyped-def]
    """The TUI's s aborts the run in progress; the demo schedule then pauses, so b's idle baseline
    measurement is not refused with "conflict" by the next run (it always was)."""
    events: list[ScheduleEvent] = []
    started = threading.Event()

    def on_event(event: ScheduleEvent) -> None:
        events.append(event)
        if event.event == "start":
            started.set()

    schedule = DemoSchedule(sim_daemon.control_endpoint, speed=0.5, on_event=on_event)
    schedule.start()
    try:
        assert started.wait(20)
        run_id = next(e.detail for e in events if e.event == "start")
        with ControlClient(sim_daemon.control_endpoint, timeout_s=20) as client:
            stopped = client.call("run.stop", {"run_id": run_id, "abort": True})
            assert stopped["state"] == "aborted"
            deadline = time.monotonic() + 20
            while not any(e.event == "aborted" for e in events) and time.monotonic() < deadline:
                time.sleep(0.1)
            assert any(e.event == "aborted" for e in events), events
            measured = client.call("baseline.measure", {"seconds": 1.0})
        assert measured and not any(e.event == "error" for e in events), events
    finally:
        schedule.stop()
