"""CURVE on the daemon's TCP sockets: encrypted, the server authenticated, optionally the clients too."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import zmq

from hdeem_watch.wire import protocol
from hdeem_watch.wire.client import ControlClient, DaemonUnreachable
from hdeem_watch.wire.keys import generate_keys, load_public_key, load_secret_key, secure_client


@pytest.mark.slow
def test_curve_daemon_serves_key_holders_only(daemon_factory: Any, receive: Any, tmp_path: Path) -> None:
    """With CURVE and an allow-list, listed clients get control and samples; others get nothing."""
    server_public, server_secret = generate_keys(tmp_path / "keys", "server")
    _, allowed_secret = generate_keys(tmp_path / "clients", "tui")
    _, stranger_secret = generate_keys(tmp_path / "others", "stranger")
    assert (server_secret.stat().st_mode & 0o777) == 0o600
    d = daemon_factory("--speed", "10", "--curve-secret-key", str(server_secret), "--curve-clients",
                       str(tmp_path / "clients"), tcp=True)
    server_key = load_public_key(server_public)
    allowed = load_secret_key(allowed_secret)
    # The fixture's readiness check uses a plain client, which CURVE refuses: start by hand.
    with open(d.stderr_path, "ab") as err:
        d.proc = subprocess.Popen(d.command(), env=d.env, stdout=subprocess.DEVNULL, stderr=err)
    with ControlClient(d.control, timeout_s=20.0, curve_server_key=server_key, curve_client_keys=allowed) as client:
        status = client.call("status")
    assert status["curve_public_key"] == server_key.decode()
    sub = zmq.Context.instance().socket(zmq.SUB)
    secure_client(sub, server_key, allowed)
    sub.connect(d.pub)
    sub.setsockopt(zmq.SUBSCRIBE, protocol.subscription(d.node, "samples"))
    assert len(receive(sub, 5.0, until=lambda m: len(m) > 5)) > 5
    sub.close(0)
    with ControlClient(d.control, timeout_s=0.5) as plain, pytest.raises(DaemonUnreachable):
        plain.call("ping")
    stranger = load_secret_key(stranger_secret)
    with ControlClient(d.control, timeout_s=0.5, curve_server_key=server_key, curve_client_keys=stranger) as other, \
            pytest.raises(DaemonUnreachable):
        other.call("ping")
    assert d.terminate() == 0, d.stderr()
    assert "CURVE: connection refused: DENIED (CURVE)" in d.stderr()  # once logged at DEBUG only (#22.14)


@pytest.mark.slow
def test_gen_keys_writes_a_pair(tmp_path: Path) -> None:
    """--gen-keys writes server.key and server.key_secret and exits 0."""
    done = subprocess.run([sys.executable, "-m", "hdeem_watch", "daemon", "--gen-keys", str(tmp_path)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    public, secret = load_secret_key(tmp_path / "server.key_secret")
    assert load_public_key(tmp_path / "server.key") == public and len(secret) == 40


def _spoil(tmp_path: Path, how: str) -> None:
    """Make the CURVE files of ``tmp_path`` unsafe in one way (the probe's and its kin)."""
    clients = tmp_path / "clients"
    if how == "clients dir 0777":
        clients.chmod(0o777)
    elif how == "clients dir of another user":
        os.chown(clients, 40003, 40003)
    elif how == "secret key 0644":
        (tmp_path / "keys" / "server.key_secret").chmod(0o644)
    elif how == "client key 0666":
        (clients / "tui.key").chmod(0o666)
    elif how == "one key under two names":
        shutil.copy(clients / "tui.key", clients / "root.key")


@pytest.mark.slow
@pytest.mark.parametrize("how", ["clients dir 0777", "clients dir of another user", "secret key 0644",
                                 "client key 0666", "one key under two names"])
def test_unsafe_curve_files_refuse_the_start_in_one_line(daemon_factory: Any, tmp_path: Path, how: str) -> None:
    """A clients directory or key others may write or read, or a key registered under two names,
    refuses the start: exit 2, one line naming the file (once accepted: another user copied their
    public key to ``root.key`` in a 0777 directory and became root over TCP)."""
    _public, secret = generate_keys(tmp_path / "keys", "server")
    generate_keys(tmp_path / "clients", "tui")
    _spoil(tmp_path, how)
    d = daemon_factory("--curve-secret-key", str(secret), "--curve-clients", str(tmp_path / "clients"), tcp=True)
    done = subprocess.run(d.command(), env=d.env, capture_output=True, text=True, timeout=30)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert "refusing to start" in lines[0] and "Traceback" not in done.stderr
    named = {"secret key 0644": "server.key_secret", "client key 0666": "tui.key",
             "one key under two names": "root.key"}.get(how, "clients")
    assert named in lines[0]


@pytest.mark.slow
def test_safe_curve_files_under_any_umask_start(daemon_factory: Any, tmp_path: Path) -> None:
    """Keys written by --gen-keys under umask 000 are still safe: the daemon starts with them."""
    old = os.umask(0)
    try:
        public, secret = generate_keys(tmp_path / "keys", "server")
        _, client_secret = generate_keys(tmp_path / "clients", "root")
    finally:
        os.umask(old)
    d = daemon_factory("--curve-secret-key", str(secret), "--curve-clients", str(tmp_path / "clients"), tcp=True)
    with open(d.stderr_path, "ab") as err:
        d.proc = subprocess.Popen(d.command(), env=d.env, stdout=subprocess.DEVNULL, stderr=err)
    with ControlClient(d.control, timeout_s=20.0, curve_server_key=load_public_key(public),
                       curve_client_keys=load_secret_key(client_secret)) as client:
        assert client.call("whoami")["role"] == "root"
    assert d.terminate() == 0, d.stderr()
