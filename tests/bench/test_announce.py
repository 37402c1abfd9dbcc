"""The announcer's bounded wait while the daemon has another run open (fake clock, no sockets)."""

from __future__ import annotations

from typing import Any

import pytest

from hdeem_watch.bench.announce import Announcer, RunRefused
from hdeem_watch.bench.schedule import RunSpec
from hdeem_watch.wire.client import ControlError

SPEC = RunSpec("triad", 4, 1 << 20, 3)


class RefusingClient:
    """Answers ``run.start`` with ``conflict`` (as the daemon does while a run is open) ``refusals``
    times, then with a run id; records the (fake) time of each request."""

    def __init__(self, refusals: int, clock: Any) -> None:
        self.refusals = refusals
        self.clock = clock
        self.calls: list[tuple[float, str]] = []

    def call(self, op: str, args: Any = None) -> Any:
        self.calls.append((self.clock(), op))
        if op == "run.start" and self.refusals > 0:
            self.refusals -= 1
            raise ControlError("conflict", "run 41 is in progress; stop it first")
        return {"run_id": 42} if op == "run.start" else {"run_id": 42, "energy_j": {}}


class Time:
    """A fake monotonic clock in seconds whose sleep advances it."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        assert seconds > 0
        self.now += seconds


def _announcer(refusals: int, wait_s: float) -> tuple[Announcer, RefusingClient, list[str]]:
    clock = Time()
    client = RefusingClient(refusals, clock)
    warnings: list[str] = []
    announcer = Announcer("ipc:///x", client=client, warn=warnings.append, wait_s=wait_s, retry_s=1.0,
                          clock=clock, sleep=clock.sleep)
    return announcer, client, warnings


def test_conflict_is_retried_every_retry_s_until_accepted() -> None:
    """Refused three times, then accepted: four run.start one second apart, the run id returned,
    a warning saying why the bench waits."""
    announcer, client, warnings = _announcer(refusals=3, wait_s=60)
    assert announcer.on_start(SPEC) == {"run_id": 42}
    assert client.calls == [(100.0, "run.start"), (101.0, "run.start"), (102.0, "run.start"), (103.0, "run.start")]
    assert warnings and "run 41 is in progress" in warnings[0] and "waiting up to 60 s" in warnings[0]
    assert announcer.enabled
    assert announcer.on_stop(SPEC) == {"daemon": {"run_id": 42, "energy_j": {}}}


def test_conflict_beyond_the_wait_raises_run_refused() -> None:
    """Still refused when ``wait_s`` is over: RunRefused naming the run, the wait and the daemon's
    reason; the last retry comes at the deadline, not after it."""
    announcer, client, _ = _announcer(refusals=1000, wait_s=2.5)
    with pytest.raises(RunRefused, match=r"still refused run.start for triad-4t after waiting 2.5 s: "
                                         r"run 41 is in progress"):
        announcer.on_start(SPEC)
    assert [t for t, _ in client.calls] == [100.0, 101.0, 102.0, 102.5]


def test_no_wait_means_one_try() -> None:
    """``wait_s=0`` asks once and raises at the first conflict."""
    announcer, client, _ = _announcer(refusals=1, wait_s=0)
    with pytest.raises(RunRefused):
        announcer.on_start(SPEC)
    assert len(client.calls) == 1
