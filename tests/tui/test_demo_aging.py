"""The headless demo on an aging simulated node names the aging pair in its first drift line (a faster
aging than the 30 %/h of the issue's 2-minute run, so the test takes ~35 s; slow)."""

from __future__ import annotations

import subprocess
import sys

import pytest


@pytest.mark.slow
def test_headless_demo_prints_a_drift_alarm_naming_the_aging_pair() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "hdeem_watch", "demo", "--headless", "--duration", "30", "--speed", "60",
         "--sim-age", "DDR_CD=+100%/h"],
        capture_output=True, text=True, timeout=180, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    drifts = [line for line in proc.stdout.splitlines() if line.startswith("drift ")]
    assert drifts, proc.stdout[-3000:]
    # the aging pair is named first (a healthy pair may follow much later at this aging rate: seen once
    # in four runs under load, after DDR_CD's; the 2-minute +30 %/h run of the issue is checked by hand)
    assert drifts[0].split()[1] == "DDR_CD" and "drifts up" in drifts[0], drifts
