"""The daemon's ZeroMQ I/O thread runs ``SCHED_BATCH``: woken by a send, it does not preempt the loop.

Thread names and policies are read as Linux shows them: ``/proc/<pid>/task/<tid>/comm`` (libzmq
names its I/O threads ``ZMQbg/IO/<n>``) and ``sched_getscheduler(2)`` of a thread id.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import zmq

from hdeem_watch.daemon.shell.publisher import quiet_io_context


def io_threads(pid: int) -> set[int]:
    """The thread ids of ``pid``'s ZeroMQ I/O threads."""
    tids = set()
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            name = Path(f"/proc/{pid}/task/{tid}/comm").read_text().strip()
        except FileNotFoundError:  # the thread ended meanwhile
            continue
        if name.startswith("ZMQbg/IO/"):
            tids.add(int(tid))
    return tids


def started_io_threads(context: zmq.Context[Any], endpoint: str) -> set[int]:
    """Start ``context``'s I/O thread with a PUB/SUB round trip over ``endpoint`` (an ipc connection
    is the I/O thread's work, so once a message crossed it, the thread has applied its policy);
    return the I/O threads it added to this process."""
    before = io_threads(os.getpid())
    pub, sub = context.socket(zmq.PUB), context.socket(zmq.SUB)
    try:
        pub.bind(endpoint)
        sub.connect(endpoint)
        sub.subscribe(b"")
        poller = zmq.Poller()
        poller.register(sub, zmq.POLLIN)
        for _ in range(200):  # a subscription takes a moment to reach the publisher
            pub.send(b"x")
            if poller.poll(25):
                break
        assert sub.recv(zmq.NOBLOCK) == b"x"
    finally:
        pub.close(0)
        sub.close(0)
    return io_threads(os.getpid()) - before


def test_the_quiet_context_runs_its_io_thread_batch_scheduled(tmp_path: Path) -> None:
    context = quiet_io_context()
    try:
        added = started_io_threads(context, f"ipc://{tmp_path}/quiet.sock")
        assert added and {os.sched_getscheduler(tid) for tid in added} == {os.SCHED_BATCH}
    finally:
        context.destroy(linger=0)
    plain = zmq.Context()  # the control: a default context's I/O thread keeps the process's policy
    try:
        added = started_io_threads(plain, f"ipc://{tmp_path}/plain.sock")
        assert added and {os.sched_getscheduler(tid) for tid in added} == {os.SCHED_OTHER}
    finally:
        plain.destroy(linger=0)


CHILD = """
import os, sys
sys.path.insert(0, sys.argv[1])
from test_quiet_io import started_io_threads
from hdeem_watch.daemon.shell.publisher import quiet_io_context
os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
context = quiet_io_context()
added = started_io_threads(context, sys.argv[2])
print(sorted({os.sched_getscheduler(tid) for tid in added}))
context.destroy(linger=0)
"""


@pytest.mark.slow
def test_a_process_run_idle_keeps_its_policy(tmp_path: Path) -> None:
    """Leaving ``SCHED_IDLE`` needs a privilege and libzmq aborts when its change is refused: the
    quiet context leaves such a process's I/O thread as it is (here, with a privilege or not)."""
    done = subprocess.run([sys.executable, "-c", CHILD, str(Path(__file__).parent), f"ipc://{tmp_path}/idle.sock"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == f"[{os.SCHED_IDLE}]"


@pytest.mark.slow
def test_the_daemon_process_sends_through_a_batch_scheduled_io_thread(shared_daemon: Any) -> None:
    pid = shared_daemon.proc.pid
    tids = io_threads(pid)
    assert tids and {os.sched_getscheduler(tid) for tid in tids} == {os.SCHED_BATCH}
    assert os.sched_getscheduler(pid) == os.SCHED_OTHER  # the loop itself is scheduled as before
