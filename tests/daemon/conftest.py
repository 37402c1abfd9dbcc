"""Fixtures of the daemon tests: the daemon as a real process on ipc sockets in a temporary directory."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import zmq

from hdeem_watch.wire import protocol
from hdeem_watch.wire.client import ControlClient, DaemonUnreachable

SRC = Path(__file__).resolve().parents[2] / "src"


def free_port() -> int:
    """A free TCP port on the loopback interface."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class DaemonProcess:
    """A daemon started by a test: its process, endpoints and state directory."""

    directory: Path
    args: list[str]
    env: dict[str, str]
    node: str = "testnode"
    tcp: bool = False
    proc: subprocess.Popen[bytes] | None = None
    stderr_path: Path = field(init=False)

    def __post_init__(self) -> None:
        self.stderr_path = self.directory / "daemon.err"
        if self.tcp:
            self._pub, self._control = f"tcp://127.0.0.1:{free_port()}", f"tcp://127.0.0.1:{free_port()}"
        else:
            self._pub, self._control = f"ipc://{self.directory}/p.sock", f"ipc://{self.directory}/c.sock"

    @property
    def pub(self) -> str:
        return self._pub

    @property
    def control(self) -> str:
        return self._control

    @property
    def state_dir(self) -> Path:
        return self.directory / "state"

    def command(self) -> list[str]:
        return [
            sys.executable, "-m", "hdeem_watch", "daemon", "--source", "sim", "--pub", self.pub,
            "--control", self.control, "--state-dir", str(self.state_dir), "--node", self.node, *self.args,
        ]

    def start(self, timeout_s: float = 30.0) -> DaemonProcess:
        with open(self.stderr_path, "ab") as err:
            self.proc = subprocess.Popen(self.command(), env=self.env, stdout=subprocess.DEVNULL, stderr=err)
        deadline = time.monotonic() + timeout_s
        with ControlClient(self.control, timeout_s=1.0) as client:
            while True:
                if self.proc.poll() is not None:
                    raise RuntimeError(f"daemon exited with {self.proc.returncode}: {self.stderr()}")
                try:
                    client.call("ping")
                    return self
                except DaemonUnreachable:
                    if time.monotonic() > deadline:
                        raise
                    time.sleep(0.05)

    def client(self, timeout_s: float = 10.0, socket_type: str = "dealer") -> ControlClient:
        return ControlClient(self.control, timeout_s=timeout_s, socket_type=socket_type)

    def stderr(self) -> str:
        return self.stderr_path.read_text() if self.stderr_path.exists() else ""

    def terminate(self, timeout_s: float = 15.0) -> int:
        assert self.proc is not None
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        return self.proc.wait(timeout=timeout_s)

    def kill9(self) -> None:
        assert self.proc is not None
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(timeout=10)

    def subscriber(self, prefix: bytes = b"hw1/", rcvhwm: int = 100_000) -> zmq.Socket:
        sock = zmq.Context.instance().socket(zmq.SUB)
        sock.setsockopt(zmq.RCVHWM, rcvhwm)
        sock.setsockopt(zmq.LINGER, 0)
        sock.connect(self.pub)
        sock.setsockopt(zmq.SUBSCRIBE, prefix)
        return sock


def daemon_env(**extra: str) -> dict[str, str]:
    """The environment of a daemon process: the package importable, no inherited HDEEM_WATCH_* settings."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("HDEEM_WATCH_")}
    env["PYTHONPATH"] = str(SRC) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env.update(extra)
    return env


def make_daemon(directory: Path, *args: str, tcp: bool = False, **env: str) -> DaemonProcess:
    directory.mkdir(parents=True, exist_ok=True)
    return DaemonProcess(directory=directory, args=list(args), env=daemon_env(**env), tcp=tcp)


@pytest.fixture
def daemon_factory(tmp_path: Path) -> Iterator[object]:
    """Build (not start) daemons in ``tmp_path``; every one still running is terminated at the end."""
    made: list[DaemonProcess] = []

    def factory(*args: str, name: str = "d", tcp: bool = False, **env: str) -> DaemonProcess:
        d = make_daemon(tmp_path / name, *args, tcp=tcp, **env)
        made.append(d)
        return d

    yield factory
    for d in made:
        if d.proc is not None and d.proc.poll() is None:
            d.proc.kill()
            d.proc.wait(timeout=10)


@pytest.fixture(scope="session")
def shared_daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProcess]:
    """One sim daemon at speed 10 (with a Prometheus endpoint) shared by the read-mostly tests.

    It re-publishes calib/baseline and looks for quiet periods every 0.5 s, with 2 s quiet windows.
    """
    port = free_port()
    d = make_daemon(tmp_path_factory.mktemp("shared"), "--speed", "10", "--prometheus", str(port),
                    HDEEM_WATCH_SNDHWM="2000", HDEEM_WATCH_REPUBLISH_S="0.5", HDEEM_WATCH_QUIET_WINDOW_S="2")
    d.prometheus_port = port  # type: ignore[attr-defined]
    d.start()
    yield d
    code = d.terminate()
    assert code == 0, d.stderr()


def receive(sock: zmq.Socket, seconds: float, *, until: object = None) -> list[protocol.Message]:
    """Every message ``sock`` receives within ``seconds`` (stopping early when ``until(messages)``)."""
    messages: list[protocol.Message] = []
    deadline = time.monotonic() + seconds
    poller = zmq.Poller()
    poller.register(sock, zmq.POLLIN)
    while (left := deadline - time.monotonic()) > 0:
        if poller.poll(int(left * 1000) + 1):
            messages.append(protocol.decode(sock.recv_multipart()))
            if until is not None and until(messages):  # type: ignore[operator]
                break
    return messages


@pytest.fixture(name="receive", scope="session")
def receive_fixture() -> object:
    """The :func:`receive` helper (test modules cannot import conftest in importlib mode)."""
    return receive
