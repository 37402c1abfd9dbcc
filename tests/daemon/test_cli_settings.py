"""Bad daemon settings are one line and exit 2 at start (#20, #22.14): binary config, negative seed,
unknown currents, a missing memspec, out-of-range values naming their file, insecure TCP."""

from __future__ import annotations

import logging
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import zmq

from hdeem_watch.config import load_settings
from hdeem_watch.errors import InputError


def _daemon(tmp_path: Path, env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, "-m", "hdeem_watch", "daemon", "--pub", f"ipc://{tmp_path}/p.sock",
               "--control", f"ipc://{tmp_path}/c.sock", "--state-dir", str(tmp_path / "state"), *args]
    return subprocess.run(command, env=env, capture_output=True, text=True, timeout=60)


def _one_line(result: subprocess.CompletedProcess[str]) -> str:
    assert result.returncode == 2, result.stderr[-2000:]
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr[-2000:]
    return lines[0]


@pytest.fixture
def env() -> dict[str, str]:
    import os

    src = str(Path(__file__).resolve().parents[2] / "src")
    environment = {k: v for k, v in os.environ.items() if not k.startswith("HDEEM_WATCH_")}
    environment["PYTHONPATH"] = src
    return environment


@pytest.mark.slow
def test_a_binary_config_file_is_one_line(tmp_path: Path, env: dict[str, str]) -> None:
    """--config on a binary file (old: UnicodeDecodeError traceback, exit 1)."""
    config = tmp_path / "cfg.bin"
    config.write_bytes(bytes(range(256)) * 4)
    line = _one_line(_daemon(tmp_path, env, "--config", str(config)))
    assert str(config) in line and "not a text file" in line


@pytest.mark.slow
def test_a_negative_seed_is_one_line(tmp_path: Path, env: dict[str, str]) -> None:
    """--seed -1 (old: numpy ValueError traceback, exit 1)."""
    line = _one_line(_daemon(tmp_path, env, "--seed", "-1"))
    assert "--seed" in line and "seed = -1" in line


@pytest.mark.slow
def test_unknown_currents_and_a_missing_memspec_stop_the_start(tmp_path: Path, env: dict[str, str]) -> None:
    """currents = [idd0, idd9] and --memspec nonexistent.json: exit 2 at start (old: ran with a WARNING)."""
    config = tmp_path / "cfg.toml"
    config.write_text('currents = ["idd0", "idd9"]\n')
    line = _one_line(_daemon(tmp_path, env, "--config", str(config)))
    assert str(config) in line and "'idd9'" in line and "idd2n" in line
    line = _one_line(_daemon(tmp_path, env, "--memspec", str(tmp_path / "nonexistent.json")))
    assert "--memspec" in line and "nonexistent.json" in line


def test_a_value_out_of_range_names_its_file(tmp_path: Path) -> None:
    """speed = -3 in the TOML: the error names the file, like every other config error (old: it did not)."""
    config = tmp_path / "cfg.toml"
    config.write_text("speed = -3\n")
    with pytest.raises(InputError, match=rf"^{config}: speed = -3.0; expected a number > 0$"):
        load_settings(config, env={})
    with pytest.raises(InputError, match=r"^environment HDEEM_WATCH_DIMMS: dimms = 0"):
        load_settings(env={"HDEEM_WATCH_DIMMS": "0"})


def test_insecure_tcp_needs_an_explicit_yes(tmp_path: Path) -> None:
    """Non-loopback TCP without CURVE is refused unless allow_insecure_tcp; loopback and CURVE need nothing."""
    with pytest.raises(InputError, match=r"--pub: pub = 'tcp://0.0.0.0:5590'.*allow_insecure_tcp"):
        load_settings(env={}, overrides={"pub": "tcp://0.0.0.0:5590"})
    config = tmp_path / "cfg.toml"
    config.write_text('control = "tcp://*:5591"\n')
    with pytest.raises(InputError, match=rf"^{config}: control = 'tcp://\*:5591'"):
        load_settings(config, env={})
    assert load_settings(config, env={"HDEEM_WATCH_ALLOW_INSECURE_TCP": "true"}).allow_insecure_tcp
    assert load_settings(env={}, overrides={"pub": "tcp://127.0.0.1:5590", "control": "tcp://[::1]:5591"})
    assert load_settings(env={}, overrides={"pub": "tcp://*:5590", "curve_secret_key_file": "/k.key_secret"})


def test_insecure_tcp_is_warned_about_loudly(caplog: Any) -> None:
    """When allowed, each insecure socket logs a WARNING before it binds (here a bind that then fails)."""
    from hdeem_watch.daemon.shell.control import ControlServer
    from hdeem_watch.daemon.shell.publisher import Publisher

    context = zmq.Context.instance()
    with caplog.at_level(logging.WARNING, logger="hdeem_watch.daemon"):
        with pytest.raises(zmq.ZMQError):
            Publisher(context, "tcp://no-such-interface-h3b:0", node="n")
        with pytest.raises(zmq.ZMQError):
            ControlServer(context, "tcp://no-such-interface-h3b:0", {})
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any("stream tcp://no-such-interface-h3b:0: TCP without CURVE" in w for w in warnings)
    assert any("control tcp://no-such-interface-h3b:0: TCP without CURVE" in w for w in warnings)
