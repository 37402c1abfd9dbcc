"""The headless demo on an aging simulated node names the aging pair in its first drift line (a faster
aging than the 30 %/h of the issue's 2-minute run; the test stops the demo with Ctrl-C at that first
drift line, so it lasts as long as the alarm takes to come, at most ``--duration``; slow)."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading

import pytest


@pytest.mark.slow
def test_headless_demo_prints_a_drift_alarm_naming_the_aging_pair() -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "hdeem_watch", "demo", "--headless", "--duration", "90", "--speed", "60",
         "--sim-age", "DDR_CD=+100%/h"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert proc.stdout is not None and proc.stderr is not None
    watchdog = threading.Timer(180, proc.kill)  # a hung demo fails the test instead of hanging it
    watchdog.start()
    lines: list[str] = []
    try:
        for line in proc.stdout:  # the demo flushes every line
            lines.append(line.rstrip("\n"))
            if line.startswith("drift "):
                proc.send_signal(signal.SIGINT)  # the first drift line is all this test reads
                break
        rest, err = proc.communicate(timeout=60)
    finally:
        watchdog.cancel()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    stdout = "\n".join(lines) + "\n" + rest
    drifts = [line for line in lines if line.startswith("drift ")]
    assert drifts, stdout[-3000:] + err[-2000:]
    # stopped by Ctrl-C at the first drift line (130), or it ended on its own at --duration (0)
    assert proc.returncode in (0, 130) and "Traceback" not in err, err[-3000:]
    # the aging pair is named first (a healthy pair may follow much later at this aging rate: seen once
    # in four runs under load, after DDR_CD's; the 2-minute +30 %/h run of the issue is checked by hand)
    assert drifts[0].split()[1] == "DDR_CD" and "drifts up" in drifts[0], drifts
