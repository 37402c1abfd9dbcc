"""Ctrl-C ends the demo promptly and says what it waits for (issue 28: ~6 s in silence)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"


@pytest.mark.slow
def test_ctrl_c_ends_the_headless_demo_within_two_seconds_saying_what_it_waits_for() -> None:
    proc = subprocess.Popen([sys.executable, "-m", "hdeem_watch", "demo", "--headless"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env={"PYTHONPATH": str(SRC), "PATH": "/usr/bin:/bin"})
    deadline = time.monotonic() + 60
    assert proc.stdout is not None
    while "power" not in proc.stdout.readline():  # the daemon is up and streaming
        assert time.monotonic() < deadline and proc.poll() is None
    began = time.monotonic()
    proc.send_signal(signal.SIGINT)
    _out, err = proc.communicate(timeout=30)
    assert proc.returncode == 130 and time.monotonic() - began <= 2.0
    assert "interrupted; stopping the run in progress, the feed and the sim daemon" in err
    assert "Traceback" not in err
