"""Fixtures shared by every test package."""

from __future__ import annotations

import importlib.util
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path
from typing import Any

import pytest


class FakeClock:
    """A monotonic clock in integer nanoseconds that moves only when a test moves it.

    Example:
        >>> clock = FakeClock(1_000)
        >>> clock.t += 500
        >>> clock()
        1500
    """

    def __init__(self, start_ns: int = 0) -> None:
        self.t = start_ns

    def __call__(self) -> int:
        return self.t


@pytest.fixture
def fake_clock() -> Callable[..., FakeClock]:
    """Make fake clocks: ``clock = fake_clock()`` (starts at 0 ns) or ``fake_clock(start_ns)``;
    pass ``clock`` where a ``clock=`` is injected and set or advance ``clock.t`` (ns)."""
    return FakeClock


@contextmanager
def _serving(server: Any, poll_ms: int = 10) -> Iterator[None]:
    """Answer ``server``'s requests (a :class:`~hdeem_watch.daemon.control.ControlServer`) on a
    thread while the block runs, as the daemon's loop would."""
    halt = threading.Event()

    def serve() -> None:
        while not halt.is_set():
            if server.socket.poll(poll_ms):
                server.handle()

    thread = threading.Thread(target=serve, name="serve-control")
    thread.start()
    try:
        yield
    finally:
        halt.set()
        thread.join()


@pytest.fixture
def serve_control() -> Callable[..., AbstractContextManager[None]]:
    """``with serve_control(server): ...`` answers a ControlServer's requests on a thread meanwhile."""
    return _serving


def _build_trees(generator: str, dest: Path) -> Path:
    """Run ``build(dest)`` of a fixture-tree generator module (a file under tests/)."""
    path = Path(__file__).resolve().parent / generator
    spec = importlib.util.spec_from_file_location(f"_trees_{path.stem}", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return Path(module.build(dest))


@pytest.fixture(scope="session")
def node_trees(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The node fixtures (``<node>/sys``, ``<node>/dmidecode.txt``), built by tests/node/make_fixtures.py."""
    return _build_trees("node/make_fixtures.py", tmp_path_factory.mktemp("node_trees"))


@pytest.fixture(scope="session")
def pmu_trees(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The perf PMU trees (``sysfs_<host>/bus/event_source/devices``), built by tests/counters/pmu_trees.py."""
    return _build_trees("counters/pmu_trees.py", tmp_path_factory.mktemp("pmu_trees"))


@pytest.fixture(scope="session")
def powercap_trees(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The powercap and perf ``power`` trees, built by tests/sources/powercap_trees.py (tests that
    write counters copy a tree first, with ``symlinks=True``)."""
    return _build_trees("sources/powercap_trees.py", tmp_path_factory.mktemp("powercap_trees"))
