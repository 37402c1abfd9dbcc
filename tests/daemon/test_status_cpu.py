"""The heartbeat's ``process.cpu_percent``: the daemon's CPU time over real time since the previous
heartbeat, in percent of one core (read from the process's CPU clock, not parsed from ``/proc``)."""

from __future__ import annotations

import os
import time
from typing import Any

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


def test_a_busy_heartbeat_period_shows_most_of_a_core_and_the_first_heartbeat_a_figure() -> None:
    clock = [0]
    book = NodeState([ChannelInfo("DDR_AB", 100.0, "dram")], node="n1", monotonic=lambda: clock[0],
                     wall=lambda: clock[0])
    captured = Captured()
    reporter = Reporter(book, Calibration(), Healthy(), captured, store=Healthy(),  # type: ignore[arg-type]
                        identity=Identity("sim", {}), poll_interval_ns=lambda: 40_000_000, clock=lambda: clock[0])
    first = _status_cpu(reporter, captured)
    assert first >= 0.0  # a figure since the reporter was made, not NaN
    end = time.process_time() + 0.15
    while time.process_time() < end:  # this thread busy: the process used (at least) most of a core
        pass
    busy = _status_cpu(reporter, captured)
    assert 50.0 < busy < 100.0 * (1 + len(os.sched_getaffinity(0)))
