"""The chunk pipeline (dram/pipeline.py) and the simulation it runs."""

from __future__ import annotations

import dataclasses
import threading
from typing import Any

import numpy as np
import pytest

from hdeem_watch.dram import pipeline
from hdeem_watch.dram.kernels import kernel_requests
from hdeem_watch.dram.memspec import load_memspec


@dataclasses.dataclass(frozen=True)
class _Pair:
    left: np.ndarray
    right: np.ndarray | None


def _chunk(i: int) -> tuple[Any, ...]:
    values = np.arange(1000 * (i + 1), dtype=np.int64) * (i + 1)
    return values, None, values.astype(np.int8), _Pair(values[::2].copy(), None if i % 2 else values[:3].copy())


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["process", "thread", "inline"])
@pytest.mark.parametrize("slot_bytes", [1 << 20, 1 << 10])
def test_every_mode_yields_the_prepared_chunks_in_order(mode: str, slot_bytes: int) -> None:
    """Each mode yields prepare(0..n-1) in order with equal arrays, None and dataclasses kept,
    whether the chunk fits a shared slot or goes through the pipe (small slots)."""
    pieces = 7  # more than the ring's slots: slots are reused
    seen = []
    for i, result in enumerate(pipeline.prepared(_chunk, pieces, mode, slot_bytes)):
        expected = _chunk(i)
        assert result[1] is None
        for got, want in ((result[0], expected[0]), (result[2], expected[2]),
                          (result[3].left, expected[3].left)):
            assert got.dtype == want.dtype and np.array_equal(got, want)
        assert (result[3].right is None) == (expected[3].right is None)
        if expected[3].right is not None:
            assert np.array_equal(result[3].right, expected[3].right)
        seen.append(i)
    assert seen == list(range(pieces))


#: Forking is safe only in a single-threaded process, and a test process is not one for long
#: (pyzmq's garbage-collector thread, for one, outlives the daemon tests that start it): the
#: process-mode checks run in a fresh interpreter.
FRESH_PROCESS_CHECKS = {
    "prepares in a worker": """
import os
import numpy as np
from hdeem_watch.dram import pipeline
def pid(i):
    return (np.array([os.getpid(), i]),)
assert pipeline.process_safe()
pids = {int(r[0][0]) for r in pipeline.prepared(pid, 5, "process")}
assert len(pids) == 1 and os.getpid() not in pids, pids
""",
    "an early stop ends the worker": """
import threading
import numpy as np
from hdeem_watch.dram import pipeline
def chunk(i):
    return (np.arange(1000 * (i + 1), dtype=np.int64),)
for i, _ in enumerate(pipeline.prepared(chunk, 50, "process", 1 << 20)):
    if i == 2:
        break
assert threading.active_count() == 1, threading.enumerate()
""",
}


@pytest.mark.slow
@pytest.mark.parametrize("check", sorted(FRESH_PROCESS_CHECKS))
def test_process_mode_in_a_single_threaded_process(check: str) -> None:
    """In a single-threaded process, "process" mode prepares every chunk in one forked worker, and
    leaving the loop early ends that worker (no zombie, no hang, no thread left)."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", FRESH_PROCESS_CHECKS[check]], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr


def _failing(i: int) -> tuple[object, ...]:
    if i == 4:
        raise ValueError("chunk 4 is bad")
    return (np.zeros(10),)


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["process", "thread", "inline"])
def test_an_error_while_preparing_reaches_the_consumer(mode: str) -> None:
    """An exception in the preparing stage is raised to the consumer (from the worker process too)."""
    with pytest.raises(ValueError, match="chunk 4 is bad"):
        for _ in pipeline.prepared(_failing, 6, mode, 1 << 16):
            pass


def test_process_mode_is_not_used_with_other_threads_running() -> None:
    """With a second thread alive, forking is unsafe: process mode falls back to a thread."""
    stop = threading.Event()
    other = threading.Thread(target=stop.wait)
    other.start()
    try:
        assert not pipeline.process_safe()
        assert [int(r[0].size) for r in pipeline.prepared(_chunk, 3, "process")] == [1000, 2000, 3000]
    finally:
        stop.set()
        other.join()


@pytest.mark.slow
@pytest.mark.parametrize("policy", ["open", "closed"])
def test_simulation_is_identical_in_every_pipeline_mode(spec, policy: str, monkeypatch: pytest.MonkeyPatch) -> None:  # type: ignore[no-untyped-def]
    """Worker process, thread or none, and row outcomes computed ahead or not: the same statistics."""
    import hdeem_watch.dram.controller as controller

    monkeypatch.setattr(controller, "CHUNK_REQUESTS", 1 << 12)
    addresses, is_write = kernel_requests("triad", 8 * 9000, threads=3)
    results = []
    for pipelined, process, ahead in ((False, False, False), (True, True, False), (True, True, True),
                                      (True, False, True)):
        monkeypatch.setattr(controller, "PIPELINE", pipelined)
        monkeypatch.setattr(controller, "PIPELINE_PROCESS", process)
        monkeypatch.setattr(controller, "OUTCOMES_AHEAD", ahead)
        results.append(controller.simulate(spec, addresses, is_write, policy=policy))
    first = results[0]
    for other in results[1:]:
        assert other.stats == first.stats and other.cycles == first.cycles
        assert (other.row_hits, other.row_misses, other.row_conflicts) == (
            first.row_hits, first.row_misses, first.row_conflicts)


@pytest.fixture
def spec():  # type: ignore[no-untyped-def]
    from pathlib import Path

    return load_memspec(Path(__file__).resolve().parents[1] / "data" / "ramulator" / "ddr4_2133P_8Gb_x8_2r_8dev.json")


def test_split_work_fills_both_halves_and_reports_a_failed_half() -> None:
    """split_work fills entries lo:hi of every output from both halves; a False half gives None."""
    def square(lo: int, hi: int, out: tuple[np.ndarray, ...]) -> bool:
        out[0][:] = np.arange(lo, hi) ** 2
        out[1][:] = np.arange(lo, hi) % 2 == 1
        return True

    result = pipeline.split_work(square, 1001, (np.int64, np.bool_))
    assert result is not None
    assert np.array_equal(result[0], np.arange(1001) ** 2) and np.array_equal(result[1], np.arange(1001) % 2 == 1)
    for bad_half in (0, 1):
        def fails(lo: int, hi: int, out: tuple[np.ndarray, ...], bad_half: int = bad_half) -> bool:
            return (lo == 0) != bool(bad_half)

        assert pipeline.split_work(fails, 10, (np.int64,)) is None
