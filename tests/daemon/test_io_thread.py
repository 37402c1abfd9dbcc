"""The daemon's ZeroMQ I/O thread runs under SCHED_BATCH (``daemon_context``): woken by a send it
does not preempt the poll loop, so it writes a poll's messages in one go (about 1 wake-up a poll
instead of ~3.8 with 4 subscribers, docs/performance.md "Stop 41")."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

import pytest
import zmq

from hdeem_watch.daemon.shell.publisher import daemon_context

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="SCHED_BATCH is Linux's")


def _threads(pid: int) -> dict[str, int]:
    """Thread name → thread id of ``pid`` (the first of each name)."""
    out: dict[str, int] = {}
    for task in sorted(Path(f"/proc/{pid}/task").iterdir()):
        out.setdefault((task / "comm").read_text().strip(), int(task.name))
    return out


def test_a_daemon_context_asks_for_sched_batch_before_its_io_thread_starts() -> None:
    context = daemon_context()
    try:
        assert context.get(zmq.THREAD_SCHED_POLICY) == os.SCHED_BATCH
        sock = context.socket(zmq.PUB)  # starts the I/O thread with the policy (checked in the process below)
        sock.bind("inproc://io-thread-test")
        sock.close(linger=0)
    finally:
        context.destroy(linger=0)


@pytest.mark.slow
def test_the_daemon_process_runs_its_io_thread_under_sched_batch_and_exits_cleanly(daemon_factory: Any) -> None:
    d = daemon_factory().start()
    assert d.proc is not None
    threads = _threads(d.proc.pid)
    assert os.sched_getscheduler(threads["ZMQbg/IO/0"]) == os.SCHED_BATCH
    assert os.sched_getscheduler(d.proc.pid) == os.SCHED_OTHER  # the poll loop itself: as before
    assert d.terminate() == 0, d.stderr()
