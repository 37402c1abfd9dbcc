"""The per-pair calibration view in a real 80×24 terminal (tmux): the demo's pairs get their own
fits, ``g`` shows them beside the datasheet and the node fit, ``esc`` returns, ``q`` quits."""

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

PAIRS = ["DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH", "node"]
FIT = re.compile(r"^\s*\d+\.\d(±\d+(\.\d)?)?$")


def _tmux(*args: str) -> str:
    return subprocess.run(["tmux", *args], capture_output=True, text=True, check=False).stdout


def _per_pair_rows(screen: str) -> dict[str, list[str]]:
    """``{current: [datasheet, fit per pair..., node fit]}`` of the per-pair view's text."""
    rows = {}
    for line in screen.splitlines():
        parts = line.split()
        if parts and re.fullmatch(r"idd\w+", parts[0]) and len(parts) == 7:
            rows[parts[0]] = parts[1:]
    return rows


@pytest.mark.slow
@pytest.mark.tmux
@pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is installed by .ci/run")
def test_per_pair_view_in_an_80x24_terminal() -> None:
    session = f"hwpairs-{uuid.uuid4().hex[:8]}"
    command = f"{sys.executable} -m hdeem_watch demo --duration 120 --speed 20"
    env = {**os.environ, "TERM": "xterm-256color"}
    subprocess.run(["tmux", "new-session", "-d", "-s", session, "-x", "80", "-y", "24", command], check=True, env=env)
    try:
        pane_pid = int(_tmux("display-message", "-p", "-t", session, "#{pane_pid}").strip())
        deadline = time.monotonic() + 60
        screen = ""
        while time.monotonic() < deadline:
            screen = _tmux("capture-pane", "-p", "-t", session)
            if "calibration (" in screen:  # runs are being fitted
                break
            time.sleep(0.5)
        assert "calibration (" in screen, screen
        time.sleep(3.0)
        subprocess.run(["tmux", "send-keys", "-t", session, "g"], check=True)
        rows: dict[str, list[str]] = {}
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            screen = _tmux("capture-pane", "-p", "-t", session)
            rows = _per_pair_rows(screen)
            if len(rows) >= 5 and all(FIT.match(v) for values in rows.values() for v in values):
                break
            time.sleep(0.5)
        assert "per-pair calibration" in screen and screen.count("\n") <= 24, screen
        header = next(line for line in screen.splitlines() if "DDR_AB" in line)
        assert header.split() == ["datash", *PAIRS], screen
        assert len(rows) >= 5 and all(FIT.match(v) for values in rows.values() for v in values), screen
        assert all(len(line) <= 80 for line in screen.splitlines())
        subprocess.run(["tmux", "send-keys", "-t", session, "Escape"], check=True)
        time.sleep(1.5)
        assert "per-pair calibration" not in _tmux("capture-pane", "-p", "-t", session)
        children = psutil.Process(pane_pid).children(recursive=True)
        subprocess.run(["tmux", "send-keys", "-t", session, "q"], check=True)
        _, alive = psutil.wait_procs([psutil.Process(pane_pid), *children], timeout=20)
        assert not [p for p in alive if p.is_running() and p.status() != psutil.STATUS_ZOMBIE]
    finally:
        subprocess.run(["tmux", "kill-session", "-t", session], capture_output=True, check=False)
