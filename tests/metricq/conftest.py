"""Fixtures of the MetricQ tests: a private RabbitMQ node, the manager stand-in, a sim daemon."""

from __future__ import annotations

import importlib.util
import itertools
import sys
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from types import ModuleType

import pytest

HERE = Path(__file__).resolve().parent


def _load(name: str, path: Path) -> ModuleType:
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


#: tests/metricq/standin.py (broker, manager stand-in, recording sink).
standin = _load("hdeem_watch_tests_metricq_standin", HERE / "standin.py")
#: tests/daemon/conftest.py: the daemon as a real process (make_daemon, DaemonProcess).
daemon_fixtures = _load("hdeem_watch_tests_daemon_fixtures", HERE.parent / "daemon" / "conftest.py")


@pytest.fixture(name="standin")
def standin_fixture() -> ModuleType:
    """The :mod:`standin` module (Broker, ManagerStandIn, RecordingSink)."""
    return standin


@pytest.fixture(name="daemon_fixtures")
def daemon_fixtures_fixture() -> ModuleType:
    """tests/daemon/conftest.py as a module (make_daemon, DaemonProcess)."""
    return daemon_fixtures


#: Vhosts of the shared node: one per test that asks for ``broker`` (more than this module has tests).
VHOSTS = tuple(f"test{i}" for i in range(16))
_next_vhost = itertools.count()


class VhostBroker:
    """One test's view of the shared RabbitMQ node: its own vhost (no exchange, queue or message of
    another test is visible there), and the node itself to stop, start or kill."""

    def __init__(self, node: object, vhost: str) -> None:
        self.node = node
        self.url: str = node.vhost_url(vhost)  # type: ignore[attr-defined]

    @property
    def proc(self) -> object:
        return self.node.proc  # type: ignore[attr-defined]

    def start(self) -> object:
        return self.node.start()  # type: ignore[attr-defined]

    def stop(self) -> None:
        self.node.stop()  # type: ignore[attr-defined]


@pytest.fixture(scope="module")
def rabbit_node(tmp_path_factory: pytest.TempPathFactory) -> Iterator[object]:
    """One private RabbitMQ node for the module (its boot is ~9 s), with a vhost per test; closed
    (with its epmd) at the end."""
    node = standin.Broker(tmp_path_factory.mktemp("rabbitmq"), vhosts=VHOSTS)
    try:
        node.start()
        yield node
    finally:
        node.close()


@pytest.fixture
def broker(rabbit_node: object) -> Iterator[VhostBroker]:
    """The running RabbitMQ node as this test's own vhost (a test that stopped or killed the node and
    failed before starting it again leaves it running for the next: started here if it is down)."""
    if rabbit_node.proc is None or rabbit_node.proc.poll() is not None:  # type: ignore[attr-defined]
        rabbit_node.start()  # type: ignore[attr-defined]
    yield VhostBroker(rabbit_node, VHOSTS[next(_next_vhost)])


@pytest.fixture
async def manager(broker: object) -> AsyncIterator[object]:
    """The manager stand-in connected to ``broker``."""
    m = standin.ManagerStandIn(broker.url)  # type: ignore[attr-defined]
    await m.connect()
    yield m
    await m.stop(silent=True)


@pytest.fixture
def sim_daemon(tmp_path: Path) -> Iterator[object]:
    """A sim daemon at real-time speed that re-publishes baseline/calib every 0.5 s (2 s quiet windows)."""
    d = daemon_fixtures.make_daemon(tmp_path / "daemon", HDEEM_WATCH_REPUBLISH_S="0.5",
                                    HDEEM_WATCH_QUIET_WINDOW_S="2")
    d.start()
    yield d
    if d.proc is not None and d.proc.poll() is None:
        d.proc.kill()
        d.proc.wait(timeout=10)
