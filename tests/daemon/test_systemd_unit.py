"""The systemd unit's sandbox (#22.16): verified by systemd-analyze and closed as far as the daemon allows."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

UNIT = Path(__file__).resolve().parents[2] / "systemd" / "hdeem-watchd.service"


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze not installed")
def test_the_unit_closes_what_the_daemon_does_not_need(tmp_path: Path) -> None:
    """Exposure ≤ 1.3 (it was 1.6): /proc subset, no W+X memory, loopback-only IP, umask 077; no private user
    namespace (job owners must reach the control socket as themselves)."""
    text = UNIT.read_text()
    for line in ("ProcSubset=pid", "MemoryDenyWriteExecute=yes", "IPAddressDeny=any", "IPAddressAllow=localhost",
                 "PrivateMounts=yes", "UMask=0077", "DevicePolicy=closed", "PrivateUsers=no"):
        assert f"\n{line}\n" in text, line
    unit = tmp_path / "hdeem-watchd.service"
    unit.write_text(text.replace("/usr/bin/hdeem-watch", shutil.which("hdeem-watch") or "/bin/true"))
    verify = subprocess.run(["systemd-analyze", "verify", str(unit)], capture_output=True, text=True, timeout=60)
    assert verify.returncode == 0 and str(unit) not in verify.stdout + verify.stderr, verify.stderr
    security = subprocess.run(["systemd-analyze", "security", "--offline=yes", str(unit)], capture_output=True,
                              text=True, timeout=60)
    level = float(security.stdout.split("Overall exposure level for hdeem-watchd.service:")[1].split()[0])
    assert level <= 1.3, security.stdout
