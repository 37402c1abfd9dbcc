"""Fixtures shared by every test package."""

from __future__ import annotations

from collections.abc import Callable

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
