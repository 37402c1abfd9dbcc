"""``hdeem-watch demo`` end to end: in a real terminal (tmux), headless, and its schedule."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
import uuid

import psutil
import pytest

from hdeem_watch.tui.demo_schedule import TARGET_RUN_S, demo_round, run_seconds

DRAM = ("DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH")
NUMBER = re.compile(r"^-?\d+\.\d+$")


def _tmux(*args: str) -> str:
    return subprocess.run(["tmux", *args], capture_output=True, text=True, check=False).stdout


def _dram_values(screen: str) -> dict[str, str]:
    values = {}
    for line in screen.splitlines():
        parts = line.split()
        if len(parts) >= 2 and parts[0] in DRAM and NUMBER.match(parts[1]):
            values[parts[0]] = parts[1]
    return values


def _has_calibration_table(screen: str) -> bool:
    rows = [line for line in screen.splitlines() if re.search(r"\bidd\d\w*\s+\d+\.\d", line)]
    return "calibration" in screen and "datash" in screen and len(rows) >= 3


@pytest.mark.tmux
@pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is installed by .ci/run")
def test_demo_in_a_real_terminal() -> None:
    """In a 100×30 tmux terminal the demo shows the four DIMM pairs with changing values and a calibration table, and q stops it cleanly."""
    session = f"hwdemo-{uuid.uuid4().hex[:8]}"
    command = f"{sys.executable} -m hdeem_watch demo --duration 90"
    env = {**os.environ, "TERM": "xterm-256color"}
    subprocess.run(["tmux", "new-session", "-d", "-s", session, "-x", "100", "-y", "30", command], check=True, env=env)
    try:
        pane_pid = int(_tmux("display-message", "-p", "-t", session, "#{pane_pid}").strip())
        deadline = time.monotonic() + 60
        screen = ""
        while time.monotonic() < deadline:
            screen = _tmux("capture-pane", "-p", "-t", session)
            if len(_dram_values(screen)) == 4 and _has_calibration_table(screen):
                break
            time.sleep(0.5)
        assert len(_dram_values(screen)) == 4, screen
        assert _has_calibration_table(screen), screen
        assert "LIVE" in screen.splitlines()[0]
        first = _dram_values(screen)
        changed = False
        for _ in range(20):
            time.sleep(0.5)
            later = _dram_values(_tmux("capture-pane", "-p", "-t", session))
            if len(later) == 4 and later != first:
                changed = True
                break
        assert changed, "the DRAM values did not change on screen"
        children = psutil.Process(pane_pid).children(recursive=True)
        assert any("daemon" in " ".join(p.cmdline()) for p in children)
        subprocess.run(["tmux", "send-keys", "-t", session, "q"], check=True)
        _, alive = psutil.wait_procs([psutil.Process(pane_pid), *children], timeout=20)
        assert not alive, f"still running after q: {[p.cmdline() for p in alive]}"
    finally:
        subprocess.run(["tmux", "kill-session", "-t", session], capture_output=True, check=False)


def test_demo_headless_prints_progress_and_stops_the_daemon() -> None:
    """--headless prints runs, calibration and power as text lines and leaves no daemon behind."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "hdeem_watch", "demo", "--headless", "--duration", "10"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        children = []
        deadline = time.monotonic() + 10
        while not children and time.monotonic() < deadline:
            children = [p for p in psutil.Process(proc.pid).children(recursive=True) if "daemon" in " ".join(p.cmdline())]
            time.sleep(0.2)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    lines = out.splitlines()
    assert any(line.startswith("power ") and all(ch in line for ch in DRAM) for line in lines), out
    runs = [line for line in lines if line.startswith("run ")]
    assert len(runs) >= 3, out
    assert any(line.startswith("calib ") and "error before" in line for line in lines), out
    assert children, "the demo started no daemon subprocess"
    _, alive = psutil.wait_procs(children, timeout=10)
    assert not alive


def test_demo_schedule_runs_last_about_the_target() -> None:
    """Each demo run is sized with the modelled line rate to last about 1.5 s; a round has idle + 7 kernels at 24 threads."""
    runs = demo_round("24")
    assert runs[0].kernel == "idle" and len(runs) == 8
    assert all(r.threads == 24 for r in runs)
    for spec in runs:
        assert abs(run_seconds(spec) - TARGET_RUN_S) < 0.2 * TARGET_RUN_S
    assert len({r.repeat for r in runs[1:]}) > 1  # sized per kernel, not one constant


def test_cli_bad_input_is_exit_2() -> None:
    """Bad flags of tui/demo are one-line errors with exit code 2."""
    from hdeem_watch.cli import main

    assert main(["tui", "--connect", "node7:5591"]) == 2
    assert main(["tui", "--fps", "0"]) == 2
    assert main(["demo", "--duration", "-1"]) == 2


def test_slurm_endpoints_use_the_documented_port() -> None:
    """--slurm connects to every node of the allocation at tcp://<node>:5591 (or the given port)."""
    from hdeem_watch.cli.tui import slurm_endpoints
    from hdeem_watch.errors import InputError

    env = {"SLURM_JOB_NODELIST": "taurusi[6001-6002]"}
    assert slurm_endpoints(env=env) == ["tcp://taurusi6001:5591", "tcp://taurusi6002:5591"]
    assert slurm_endpoints(7000, env=env)[0] == "tcp://taurusi6001:7000"
    with pytest.raises(InputError):
        slurm_endpoints(env={})


def test_tui_without_a_terminal_prints_text_lines(fake_node) -> None:  # type: ignore[no-untyped-def]
    """hdeem-watch tui with stdout not a terminal falls back to text progress (and says so on stderr)."""
    done = subprocess.run(
        [sys.executable, "-m", "hdeem_watch", "tui", "--connect", fake_node.control_endpoint, "--duration", "2.5"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "not a terminal" in done.stderr
    lines = done.stdout.splitlines()
    assert any(line.startswith("state  fake1 live") for line in lines), done.stdout
    assert any(line.startswith("power ") and all(ch in line for ch in DRAM) for line in lines), done.stdout
