"""CURVE on the daemon's TCP sockets: encrypted, the server authenticated, optionally the clients too."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import zmq

from hdeem_watch.daemon import protocol
from hdeem_watch.daemon.client import ControlClient, DaemonUnreachable
from hdeem_watch.daemon.security import generate_keys, load_public_key, load_secret_key, secure_client


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
