"""Client keys that just work: where a client finds the daemon's key, and a clear, fast message
when the CURVE handshake fails (no key, a wrong key, an unregistered key, CURVE on one side)."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zmq

from hdeem_watch.addresses import remote_endpoint
from hdeem_watch.cli import curve_options
from hdeem_watch.cli import main as cli_main
from hdeem_watch.daemon.shell.control import ControlServer
from hdeem_watch.daemon.shell.endpoints import advertised_endpoints
from hdeem_watch.daemon.shell.security import CurveServer
from hdeem_watch.errors import InputError
from hdeem_watch.wire import keys as security
from hdeem_watch.wire.client import ControlClient, HandshakeFailed
from hdeem_watch.wire.handshake import MECHANISM_MISMATCH, explain
from hdeem_watch.wire.keys import (
    client_curve,
    generate_keys,
    load_public_key,
    load_secret_key,
)


def test_gen_keys_refuses_to_replace_a_pair_without_force(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A second --gen-keys keeps the pair clients hold (exit 2, one line); --force replaces it."""
    assert cli_main(["daemon", "--gen-keys", str(tmp_path)]) == 0
    first = load_public_key(tmp_path / "server.key")
    assert cli_main(["daemon", "--gen-keys", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"hdeem-watch: error: {tmp_path / 'server.key'}: exists already; refusing to replace the key "
                   "pair (clients hold its public key): use --force to write a new one"]
    assert load_public_key(tmp_path / "server.key") == first
    assert cli_main(["daemon", "--gen-keys", str(tmp_path), "--force"]) == 0
    assert load_public_key(tmp_path / "server.key") != first
    assert cli_main(["daemon", "--gen-keys", str(tmp_path), "--key-name", "alice"]) == 0
    assert (tmp_path / "alice.key_secret").stat().st_mode & 0o777 == 0o600
    assert cli_main(["daemon", "--gen-keys", str(tmp_path), "--key-name", "../x"]) == 2


def test_the_server_key_comes_from_the_flag_the_environment_or_the_node_config(tmp_path: Path) -> None:
    """Flag > $HDEEM_WATCH_SERVER_KEY (file or Z85) > the daemon config's key; a bad one is named."""
    public, secret = generate_keys(tmp_path, "server")
    other_public, _ = generate_keys(tmp_path / "other", "server")
    key = load_public_key(public)
    home = tmp_path / "home"
    none_config = {"HDEEM_WATCH_CONFIG": str(tmp_path / "absent.toml")}
    assert client_curve(env=none_config, home=home) is None
    assert client_curve(str(public), env=none_config, home=home) == security.ClientCurve(key, None, str(public))
    by_env = client_curve(env={**none_config, "HDEEM_WATCH_SERVER_KEY": str(other_public)}, home=home)
    assert by_env is not None and by_env.server_key == load_public_key(other_public)
    by_z85 = client_curve(env={**none_config, "HDEEM_WATCH_SERVER_KEY": key.decode()}, home=home)
    assert by_z85 is not None and by_z85.server_key == key
    config = tmp_path / "hdeem-watchd.toml"
    config.write_text(f'curve_secret_key_file = "{secret}"\n')  # the public .key beside it
    by_config = client_curve(env={"HDEEM_WATCH_CONFIG": str(config)}, home=home)
    assert by_config is not None and by_config.server_key == key
    config.write_text(f'[daemon]\ncurve_public_key_file = "{other_public}"\n')
    by_config = client_curve(env={"HDEEM_WATCH_CONFIG": str(config)}, home=home)
    assert by_config is not None and by_config.server_key == load_public_key(other_public)
    with pytest.raises(InputError, match=r"^--server-key: .*nope.key: not a readable ZeroMQ certificate"):
        client_curve(str(tmp_path / "nope.key"), env=none_config, home=home)
    with pytest.raises(InputError, match=r"^\$HDEEM_WATCH_SERVER_KEY: "):
        client_curve(env={**none_config, "HDEEM_WATCH_SERVER_KEY": "garbage"}, home=home)


def test_the_client_key_comes_from_the_flag_the_environment_or_the_users_config(tmp_path: Path) -> None:
    """--client-key > $HDEEM_WATCH_CLIENT_KEY > ~/.config/hdeem-watch/client.key_secret > one-off."""
    public, _ = generate_keys(tmp_path, "server")
    env = {"HDEEM_WATCH_CONFIG": str(tmp_path / "absent.toml"), "HDEEM_WATCH_SERVER_KEY": str(public)}
    home = tmp_path / "home"
    curve = client_curve(env=env, home=home)
    assert curve is not None and curve.client_keys is None
    _, mine = generate_keys(home / ".config" / "hdeem-watch", "client")
    curve = client_curve(env=env, home=home)
    assert curve is not None and curve.client_keys == load_secret_key(mine)
    _, flagged = generate_keys(tmp_path / "flag", "alice")
    curve = client_curve(client_key_file=str(flagged), env=env, home=home)
    assert curve is not None and curve.client_keys == load_secret_key(flagged)
    with pytest.raises(InputError, match=r"^--client-key: .*: has no secret key"):
        client_curve(client_key_file=str(public), env=env, home=home)
    with pytest.raises(InputError, match="needs the daemon's public key"):
        client_curve(client_key_file=str(flagged), env={"HDEEM_WATCH_CONFIG": str(tmp_path / "absent.toml")},
                     home=home)


def test_the_option_help_names_the_real_variables() -> None:
    """cli/curve_options spells the names out (to stay light); they must match the resolver's."""
    assert curve_options.SERVER_KEY_ENV == security.SERVER_KEY_ENV
    assert curve_options.CLIENT_KEY_ENV == security.CLIENT_KEY_ENV
    assert curve_options.DEFAULT_CONFIG == security.DEFAULT_CONFIG


def test_handshake_events_are_explained() -> None:
    """The decisive monitor events become one line each; others are not failures."""
    assert "requires CURVE" in str(explain(zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL, MECHANISM_MISMATCH, curve=False))
    assert "does not use CURVE" in str(explain(zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL, MECHANISM_MISMATCH, curve=True))
    assert "not registered" in str(explain(zmq.EVENT_HANDSHAKE_FAILED_AUTH, 400, curve=True))
    assert "not this daemon's" in str(explain(zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL, 32, curve=True))
    # a plain client often sees only the closed pipe when the daemon wants CURVE
    assert "requires CURVE" in str(explain(zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL, 32, curve=False))
    assert explain(zmq.EVENT_HANDSHAKE_SUCCEEDED, 0, curve=True) is None


@pytest.fixture
def curve_endpoint(tmp_path: Path, serve_control: Any) -> Iterator[tuple[str, bytes, tuple[bytes, bytes]]]:
    """A CURVE control socket on loopback TCP that admits the clients in its directory only."""
    context = zmq.Context()  # its own: the ZAP handler binds inproc://zeromq.zap.01 once per context
    _, secret = generate_keys(tmp_path, "server")
    _, allowed = generate_keys(tmp_path / "clients", "root")
    curve = CurveServer(context, str(secret), str(tmp_path / "clients"))
    server = ControlServer(context, "tcp://127.0.0.1:0", {"status": lambda args: {"up": True}}, secure=curve.apply)
    try:
        with serve_control(server):
            yield server.endpoint, curve.public, load_secret_key(allowed)
    finally:
        server.close()
        curve.close()
        context.term()


@pytest.mark.parametrize("case", ["no key", "wrong server key", "unregistered client"])
def test_a_refused_handshake_fails_at_once_with_the_reason(curve_endpoint: Any, case: str) -> None:
    """Instead of a silent wait for the 20 s timeout: HandshakeFailed within a second, naming why."""
    endpoint, server_key, allowed = curve_endpoint
    options: dict[str, Any] = {
        "no key": {},
        "wrong server key": {"curve_server_key": zmq.curve_keypair()[0], "curve_client_keys": allowed},
        "unregistered client": {"curve_server_key": server_key},
    }[case]
    expected = {"no key": "requires CURVE", "wrong server key": "not this daemon's",
                "unregistered client": "not registered"}[case]
    start = time.monotonic()
    with ControlClient(endpoint, timeout_s=20, **options) as client, pytest.raises(HandshakeFailed, match=expected):
        client.call("status")
    assert time.monotonic() - start < 3
    with ControlClient(endpoint, timeout_s=5, curve_server_key=server_key, curve_client_keys=allowed) as client:
        assert client.call("status") == {"up": True}


def test_the_status_advertises_tcp_endpoints_with_the_host_name() -> None:
    """A wildcard bind is advertised with the host's name; ipc and loopback are for this node only."""
    assert remote_endpoint("tcp://0.0.0.0:5590", "node7") == "tcp://node7:5590"
    assert remote_endpoint("tcp://*:5591", "node7") == "tcp://node7:5591"
    assert remote_endpoint("tcp://10.1.2.3:5590", "node7") == "tcp://10.1.2.3:5590"
    assert remote_endpoint("tcp://127.0.0.1:5590", "node7") is None
    assert remote_endpoint("ipc:///run/hdeem-watch/pub.sock", "node7") is None
    assert advertised_endpoints("tcp://0.0.0.0:5590", ["ipc:///run/c.sock", "tcp://0.0.0.0:5591"], "n7") == {
        "pub": "tcp://n7:5590", "control": "tcp://n7:5591"}


def test_tui_without_the_key_stops_at_once_with_the_reason(curve_endpoint: Any, capsys: pytest.CaptureFixture[str],
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """``tui`` against a CURVE daemon without its key: exit 2 and one line, not "connecting" forever."""
    endpoint, _, _ = curve_endpoint
    monkeypatch.setenv("HDEEM_WATCH_CONFIG", "/nonexistent/hdeem-watchd.toml")
    monkeypatch.delenv("HDEEM_WATCH_SERVER_KEY", raising=False)
    start = time.monotonic()
    assert cli_main(["tui", "--headless", "--connect", endpoint, "--duration", "30"]) == 2
    assert time.monotonic() - start < 5
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"hdeem-watch: error: {endpoint}: the daemon requires CURVE"), err


def test_a_plain_control_client_takes_the_keys_the_environment_names(curve_endpoint: Any, tmp_path: Path,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """``ControlClient(tcp_endpoint)`` with no keys given uses $HDEEM_WATCH_SERVER_KEY and
    $HDEEM_WATCH_CLIENT_KEY, so every client (``jobs``, scripts) just works on a configured node."""
    endpoint, server_key, allowed = curve_endpoint
    monkeypatch.setenv("HDEEM_WATCH_CONFIG", str(tmp_path / "absent.toml"))
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.delenv("XDG_CONFIG_HOME", raising=False)
    monkeypatch.setenv("HDEEM_WATCH_SERVER_KEY", server_key.decode())
    key_file = tmp_path / "clients" / "root.key_secret"  # the fixture's registered pair
    assert load_secret_key(key_file) == allowed
    monkeypatch.setenv("HDEEM_WATCH_CLIENT_KEY", str(key_file))
    with ControlClient(endpoint, timeout_s=5) as client:
        assert client.call("status") == {"up": True}
    with ControlClient(endpoint, timeout_s=5, curve_from_environment=False) as plain, \
            pytest.raises(HandshakeFailed, match="requires CURVE"):
        plain.call("status")
