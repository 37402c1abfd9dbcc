"""The heartbeat's ``process.cpu_percent``: the daemon's CPU time over real time since the previous
heartbeat, in percent of one core (read from the process's CPU clock, not parsed from ``/proc``)."""

from __future__ import annotations

import time
from typing import Any

import pytest

from hdeem_watch.daemon.book.state import NodeState
from hdeem_watch.daemon.ops.reporting import Identity, Reporter
from hdeem_watch.daemon.shell.workers import Calibration
from hdeem_watch.sources.base import ChannelInfo


class Captured:
    def __init__(self) -> None:
        self.bodies: list[tuple[str, Any]] = []

    def publish(self, kind: str, body: Any, **_: Any) -> bool:
        self.bodies.append((kind, dict(body)))
        return True


class Healthy:
    kind = "sim"

    def health(self) -> str:
        return "ok"


def _status_cpu(reporter: Reporter, captured: Captured) -> float:
    reporter.publish_status()
    kind, body = captured.bodies[-1]
    assert kind == "status"
    return float(body["process"]["cpu_percent"])


def test_the_heartbeat_shows_the_processes_cpu_time_over_real_time_since_the_previous_one() -> None:
    clock = [0]
    book = NodeState([ChannelInfo("DDR_AB", 100.0, "dram")], node="n1", monotonic=lambda: clock[0],
                     wall=lambda: clock[0])
    captured = Captured()
    reporter = Reporter(book, Calibration(), Healthy(), captured, store=Healthy(),  # type: ignore[arg-type]
                        identity=Identity("sim", {}), poll_interval_ns=lambda: 40_000_000, clock=lambda: clock[0])
    first = _status_cpu(reporter, captured)
    assert first >= 0.0  # a figure since the reporter was made, not NaN
    cpu0, wall0 = time.process_time(), time.monotonic()
    while time.process_time() < cpu0 + 0.15:  # busy: 0.15 s of CPU, however long the machine makes it take
        pass
    cpu1, wall1 = time.process_time(), time.monotonic()
    busy = _status_cpu(reporter, captured)
    expected = 100.0 * (cpu1 - cpu0) / (wall1 - wall0)  # the same figure, measured around the busy period
    assert expected > 10.0
    assert busy == pytest.approx(expected, rel=0.1)
