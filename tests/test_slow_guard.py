"""The guard of tests/conftest.py: a test not marked slow may start no process and call no sleep."""

from __future__ import annotations

import sys
import threading
import time
from typing import Any

import pytest


def test_a_process_start_fails_a_fast_test(slow_guard: Any, request: pytest.FixtureRequest) -> None:
    """The audit event every ``subprocess.Popen`` raises (sent here by hand: no process starts) is
    seen, and the check fails the test naming it and the fix."""
    assert slow_guard.active
    sys.audit("subprocess.Popen", "/bin/true", ["true"], None, None)
    assert slow_guard.found == ["started a process (subprocess.Popen /bin/true)"]
    with pytest.raises(pytest.fail.Exception, match=r"not marked slow but in its body it started a "
                       r"process \(subprocess.Popen /bin/true\): mark it @pytest.mark.slow"):
        slow_guard.check(request.node, "body")
    assert slow_guard.found == []


def test_a_sleep_here_or_on_a_thread_started_here_is_seen(slow_guard: Any) -> None:
    """``time.sleep`` on the test's thread and on a thread the test started are both recorded."""
    time.sleep(0)
    worker = threading.Thread(target=time.sleep, args=(0.0,), name="worker")
    worker.start()
    worker.join()
    found, slow_guard.found = slow_guard.found, []
    assert found == ["slept 0 s on thread 'MainThread'", "slept 0.0 s on thread 'worker'"]


@pytest.mark.slow
def test_a_slow_test_is_not_watched(slow_guard: Any) -> None:
    """Marked slow, a test may sleep: nothing is recorded."""
    time.sleep(0)
    assert not slow_guard.active and slow_guard.found == []
