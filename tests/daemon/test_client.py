"""ControlClient against a real ROUTER socket (a tiny in-test server, not the daemon)."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import zmq

from hdeem_watch.wire import protocol
from hdeem_watch.wire.client import ControlClient, ControlError, DaemonUnreachable, default_endpoints


class _Router:
    """Answers each request with its op and args echoed, after an optional delay per op."""

    def __init__(self, endpoint: str, delays: dict[str, float]) -> None:
        self.context = zmq.Context()
        self.sock = self.context.socket(zmq.ROUTER)
        self.sock.bind(endpoint)
        self.delays = delays
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        poller = zmq.Poller()
        poller.register(self.sock, zmq.POLLIN)
        while not self.stop.is_set():
            if not poller.poll(20):
                continue
            frames = self.sock.recv_multipart()
            req = protocol.decode_request(frames[-1])
            if req.op == "fail":
                body = protocol.encode_reply_error(req.id, "bad-args", "nope")
            elif req.op == "unreadable-id":  # as the daemon answers a request whose id it cannot read
                body = protocol.encode_reply_error(None, "bad-args", "integer out of range")
            else:
                self.stop.wait(self.delays.get(req.op, 0.0))
                body = protocol.encode_reply_ok(req.id, {"op": req.op, "args": req.args})
            self.sock.send_multipart([*frames[:-1], body])

    def close(self) -> None:
        self.stop.set()
        self.thread.join()
        self.sock.close(0)
        self.context.term()


@pytest.fixture
def router(tmp_path: Path) -> Iterator[str]:
    endpoint = f"ipc://{tmp_path}/control.sock"
    server = _Router(endpoint, {"slow": 0.4})
    yield endpoint
    server.close()


@pytest.mark.parametrize("socket_type", ["dealer", "req"])
def test_call_returns_result_and_raises_control_error(router: str, socket_type: str) -> None:
    """A reply's result is returned; an error reply raises ControlError with its code (REQ and DEALER)."""
    with ControlClient(router, timeout_s=2.0, socket_type=socket_type) as client:
        assert client.call("status", {"a": 1}) == {"op": "status", "args": {"a": 1}}
        with pytest.raises(ControlError) as info:
            client.call("fail")
        assert info.value.code == "bad-args"
        assert client.call("again") == {"op": "again", "args": {}}


@pytest.mark.parametrize("socket_type", ["dealer", "req"])
def test_an_error_reply_without_id_is_the_answer_not_a_timeout(router: str, socket_type: str) -> None:
    """An error reply whose id the daemon could not read (``"id": null``) answers the request in
    flight at once (once: the client waited out its timeout, 10 s per Prolog)."""
    with ControlClient(router, timeout_s=5.0, socket_type=socket_type) as client:
        began = time.monotonic()
        with pytest.raises(ControlError) as info:
            client.call("unreadable-id")
        assert time.monotonic() - began < 1.0 and info.value.code == "bad-args"
        assert client.call("again") == {"op": "again", "args": {}}


@pytest.mark.parametrize("socket_type", ["dealer", "req"])
def test_timeout_then_recovery(router: str, socket_type: str) -> None:
    """A slow reply raises DaemonUnreachable; the next call works and never returns the stale reply."""
    with ControlClient(router, timeout_s=0.1, socket_type=socket_type) as client:
        with pytest.raises(DaemonUnreachable):
            client.call("slow")
        result = client.call("quick", timeout_s=2.0)
        assert result["op"] == "quick"


def test_missing_ipc_socket_is_unreachable_at_once(tmp_path: Path) -> None:
    """With no socket file the client fails fast instead of waiting for the timeout."""
    client = ControlClient(f"ipc://{tmp_path}/none.sock", timeout_s=30.0)
    with pytest.raises(DaemonUnreachable):
        client.call("status")


def test_default_endpoints_follow_runtime_dirs(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """Default endpoints are ipc sockets in the explicit, HDEEM_WATCH, XDG or /tmp runtime directory."""
    monkeypatch.delenv("HDEEM_WATCH_RUNTIME_DIR", raising=False)
    monkeypatch.delenv("RUNTIME_DIRECTORY", raising=False)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    assert default_endpoints() == (
        f"ipc://{tmp_path}/hdeem-watch/pub.sock",
        f"ipc://{tmp_path}/hdeem-watch/control.sock",
    )
    assert default_endpoints(tmp_path / "x")[1] == f"ipc://{tmp_path}/x/control.sock"
    monkeypatch.delenv("XDG_RUNTIME_DIR")
    import os

    assert default_endpoints()[0] == f"ipc:///tmp/hdeem-watch-{os.getuid()}/pub.sock"
