"""The daemon's command line, settings precedence, shutdown, the example config and the systemd unit."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path
from typing import Any

import pytest

from hdeem_watch.config import DaemonSettings, load_settings
from hdeem_watch.errors import InputError

REPO = Path(__file__).resolve().parents[2]


def test_settings_precedence_file_env_flags(tmp_path: Path) -> None:
    """Defaults < TOML file < HDEEM_WATCH_* environment < command-line overrides; env strings are typed."""
    config = tmp_path / "d.toml"
    config.write_text('source = "sim"\nspeed = 2.0\nnode = "fromfile"\n[daemon]\nsndhwm = 7\n')
    s = load_settings(config, env={"HDEEM_WATCH_SPEED": "3", "HDEEM_WATCH_REPLAY_LOOP": "yes",
                                   "HDEEM_WATCH_CURRENTS": "idd0, IDD4R"}, overrides={"node": "flag", "seed": None})
    assert (s.speed, s.node, s.sndhwm, s.replay_loop, s.currents) == (3.0, "flag", 7, True, ("idd0", "idd4r"))
    assert load_settings(env={}).poll_interval_s == DaemonSettings().poll_interval_s


@pytest.mark.parametrize(
    ("text", "env", "needle"),
    [
        ("nope = 1\n", {}, "unknown setting 'nope'"),
        ("speed = 'fast'\n", {}, "speed"),
        ("speed = -1\n", {}, "speed"),
        ("source = 'gpu'\n", {}, "source"),
        ("source = 'replay'\n", {}, "replay_file"),
        ("speed = [\n", {}, "not valid TOML"),
        ("", {"HDEEM_WATCH_DIMMS": "eight"}, "HDEEM_WATCH_DIMMS"),
        ("", {"HDEEM_WATCH_PROMETHEUS_PORT": "70000"}, "prometheus_port"),
    ],
)
def test_bad_settings_are_one_line_input_errors(tmp_path: Path, text: str, env: dict[str, str], needle: str) -> None:
    """Unknown keys, wrong types, bad ranges and bad TOML raise InputError naming the key, on one line."""
    config = tmp_path / "bad.toml"
    config.write_text(text)
    with pytest.raises(InputError) as info:
        load_settings(config, env=env)
    assert needle in str(info.value) and "\n" not in str(info.value)


def test_example_config_loads() -> None:
    """daemon/hdeem-watchd.toml is a valid settings file with every key the settings know of."""
    example = REPO / "daemon" / "hdeem-watchd.toml"
    settings = load_settings(example, env={})
    assert settings.source == "hdeem"
    text = example.read_text()
    for name in DaemonSettings.__dataclass_fields__:
        assert name in text, f"{name} is not documented in the example config"


def _cli(*args: str, env: dict[str, str] | None = None, timeout: float = 30) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "hdeem_watch", "daemon", *args], capture_output=True, text=True,
                          timeout=timeout, env=env)


def test_bad_flags_exit_2_with_one_line(tmp_path: Path) -> None:
    """Bad flags, a bad config file or an unusable endpoint exit 2 with one line on stderr."""
    from hdeem_watch.cli import main

    for args in (["daemon", "--source", "gpu"], ["daemon", "--config", str(tmp_path / "missing.toml")],
                 ["daemon", "--pub", "bogus://x", "--control", f"ipc://{tmp_path}/c.sock",
                  "--state-dir", str(tmp_path / "s")]):
        code = main(args)
        assert code == 2, args


@pytest.mark.slow
def test_unavailable_source_is_one_line_with_the_reason(tmp_path: Path) -> None:
    """A source that cannot work here exits 2 with exactly one stderr line giving the source's reason."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("HDEEM_WATCH_")}
    env["HDEEM_WATCH_RAPL_ROOT"] = str(tmp_path / "no-powercap")
    done = _cli("--source", "rapl", "--state-dir", str(tmp_path / "s"), "--runtime-dir", str(tmp_path / "r"), env=env)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("hdeem-watch: error: source rapl:"), done.stderr
    assert "no-powercap" in lines[0]


@pytest.mark.slow
def test_second_daemon_on_the_same_state_dir_is_refused(daemon_factory: Any) -> None:
    """Two daemons cannot share a state directory: the second exits 2 with one line naming the directory."""
    first = daemon_factory("--speed", "5").start()
    done = _cli("--source", "sim", "--pub", first.pub + "2", "--control", first.control + "2",
                "--state-dir", str(first.state_dir), env=first.env)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("hdeem-watch: error: state dir") and "another" in lines[0]
    assert first.proc is not None
    first.proc.send_signal(signal.SIGINT)  # Ctrl-C is a clean stop too
    assert first.proc.wait(timeout=15) == 0, first.stderr()


@pytest.mark.slow
def test_ipc_permissions_and_prometheus_endpoint(shared_daemon: Any) -> None:
    """ipc sockets are 0660; --prometheus serves per-channel power gauges and energy counters."""
    time.sleep(1.2)  # at least one heartbeat, which updates the metrics
    port = shared_daemon.prometheus_port
    text = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5).read().decode()
    node = shared_daemon.node
    assert f'hdeem_watch_power_watts{{channel="DDR_AB",node="{node}"}}' in text
    prefix = f'hdeem_watch_energy_joules_total{{channel="BLADE",node="{node}"}}'
    value = next(line for line in text.splitlines() if line.startswith(prefix))
    assert float(value.split()[-1]) > 0
    assert "hdeem_watch_samples_total" in text
    assert (Path(shared_daemon.pub[6:]).stat().st_mode & 0o777) == 0o660
    assert (Path(shared_daemon.control[6:]).stat().st_mode & 0o777) == 0o660


def test_default_ipc_directory_is_private(tmp_path: Path) -> None:
    """Endpoints in a missing runtime directory create it 0750 and the sockets 0660."""
    import zmq

    from hdeem_watch.daemon.shell.publisher import bind_endpoint

    sock = zmq.Context.instance().socket(zmq.PUB)
    path = tmp_path / "rt" / "p.sock"
    bind_endpoint(sock, f"ipc://{path}")
    try:
        assert (path.parent.stat().st_mode & 0o777) == 0o750
        assert (path.stat().st_mode & 0o777) == 0o660
    finally:
        sock.close(0)


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze not installed")
def test_systemd_unit_verifies_and_is_hardened(tmp_path: Path) -> None:
    """systemd-analyze verify accepts the unit without a warning (a broken copy is caught); exposure ≤ 2.0."""
    unit = (REPO / "systemd" / "hdeem-watchd.service").read_text()
    exe = shutil.which("hdeem-watch") or "/bin/true"
    good = tmp_path / "hdeem-watchd.service"
    good.write_text(unit.replace("/usr/bin/hdeem-watch", exe))
    done = subprocess.run(["systemd-analyze", "verify", str(good)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and str(good) not in done.stderr + done.stdout, done.stderr
    for key in ("ProtectSystem=strict", "NoNewPrivileges=yes", "CapabilityBoundingSet=\n", "RuntimeDirectory=",
                "StateDirectory=", "User=hdeem-watch"):
        assert key in unit
    broken_dir = tmp_path / "broken"
    broken_dir.mkdir()
    broken = broken_dir / "hdeem-watchd.service"
    broken.write_text(good.read_text().replace("ProtectSystem=strict", "ProtectSystem=stricter"))
    done = subprocess.run(["systemd-analyze", "verify", str(broken)], capture_output=True, text=True, timeout=60)
    assert "ProtectSystem" in done.stderr or "stricter" in done.stderr
    security = subprocess.run(["systemd-analyze", "security", "--offline=yes", str(good)], capture_output=True,
                              text=True, timeout=60)
    level = float(security.stdout.split("Overall exposure level for hdeem-watchd.service:")[1].split()[0])
    assert level <= 2.0
    sysusers = (REPO / "systemd" / "hdeem-watchd.sysusers.conf").read_text()
    assert any(line.split()[:2] == ["u", "hdeem-watch"] for line in sysusers.splitlines() if line.strip())
