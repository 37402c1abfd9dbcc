"""Fixtures shared by every test package."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
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
