"""The guard of tests/conftest.py: a test not marked slow may start no process and call no sleep."""

from __future__ import annotations

import subprocess
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
    """``time.sleep`` called from test code on the test's thread and on a thread the test started
    are both recorded; a sleep inside the code under test (here: the threading module's) is not."""
    time.sleep(0)
    for worker in (threading.Thread(target=time.sleep, args=(0.0,), name="library"),
                   threading.Thread(target=lambda: time.sleep(0.0), name="worker")):
        worker.start()
        worker.join()
    found, slow_guard.found = slow_guard.found, []
    assert found == ["slept 0 s on thread 'MainThread'", "slept 0.0 s on thread 'worker'"]


def test_a_fixture_that_started_a_process_fails_a_fast_test_using_it(
        slow_guard: Any, request: pytest.FixtureRequest, tmp_path: Any) -> None:
    """A fixture noted as having started a process (here ``tmp_path``, noted by hand) fails a test
    not marked slow that uses it, even when the process started for an earlier test."""
    slow_guard.process_fixtures.add("tmp_path")
    try:
        with pytest.raises(pytest.fail.Exception, match="uses the fixture 'tmp_path', which started a process"):
            slow_guard.check(request.node, "setup")
    finally:
        slow_guard.process_fixtures.discard("tmp_path")


@pytest.fixture
def a_process() -> int:
    """A fixture that starts a process."""
    return subprocess.run(["true"], check=True).returncode


@pytest.mark.slow
def test_a_fixture_that_starts_a_process_is_noted(a_process: int, slow_guard: Any) -> None:
    """The fixture watch notes every fixture whose setup started a process."""
    assert "a_process" in slow_guard.process_fixtures


@pytest.mark.slow
def test_a_slow_test_is_not_watched(slow_guard: Any) -> None:
    """Marked slow, a test may sleep: nothing is recorded."""
    time.sleep(0)
    assert not slow_guard.active and slow_guard.found == []
