"""One write path: the store worker keeps no writes and retries nothing; the store's writer does."""

from __future__ import annotations

import sqlite3
import threading
from pathlib import Path
from typing import Any

from hdeem_watch.daemon.store.database import Store
from hdeem_watch.daemon.store.worker import StoreWorker


def _record(n: int) -> dict[str, Any]:
    return {"run_id": f"r{n}", "kernel": "triad", "state": "done", "t_start_ns": n}


def test_a_write_that_raises_is_not_kept_and_does_not_hold_back_the_next(tmp_path: Path) -> None:
    """A write whose action raises (a record that cannot be serialised) is reported not stored and
    made once; the writes after it are stored at once (no second backlog in front of the store's)."""
    store = Store(tmp_path / "state.db")
    worker = StoreWorker(store)
    calls: list[str] = []
    results: list[bool] = []

    def broken(_store: Any) -> bool:
        calls.append("broken")
        raise OSError(28, "No space left on device")

    worker.write("broken", broken, results.append)
    worker.write("run r1", lambda s: s.save_run(_record(1)), results.append)
    worker.write("run r2", lambda s: s.save_run(_record(2)), results.append)
    worker.shutdown()
    worker.collect()
    assert results == [False, True, True]
    assert calls == ["broken"]
    assert worker.health() == "ok"
    store.close()
    reopened = Store(tmp_path / "state.db")
    assert [r["run_id"] for r in reopened.list_runs()] == ["r2", "r1"]
    reopened.close()


def test_while_the_disk_fails_one_writer_keeps_every_write_and_one_health_says_so(tmp_path: Path) -> None:
    """With the writer's disk failing, the worker's writes are acknowledged as not stored, the
    worker's health is the store's (one string), one writer thread holds them all, and once the
    disk is back every one of them is on disk."""
    before = set(threading.enumerate())
    store = Store(tmp_path / "state.db", retry_min_s=0.01, retry_max_s=0.05)
    writer = store._writer
    failing = threading.Event()
    failing.set()
    apply = writer._apply

    def flaky(db: sqlite3.Connection, op: Any) -> None:
        if failing.is_set():
            raise sqlite3.OperationalError("database or disk is full")
        apply(db, op)

    writer._apply = flaky  # type: ignore[method-assign]
    worker = StoreWorker(store)
    results: list[bool] = []
    for n in range(1, 51):
        worker.write(f"run r{n}", lambda s, n=n: s.save_run(_record(n)), results.append)  # type: ignore[misc]
    worker.shutdown()
    worker.collect()
    assert results == [False] * 50
    assert worker.health() == store.health()
    assert worker.health().startswith("degraded: state database not writable (database or disk is full)")
    assert writer.pending == 50
    writers = [t for t in threading.enumerate() if t.name == "hdeem-watch-state-writer" and t not in before]
    assert len(writers) == 1
    failing.clear()
    assert store.flush(5.0)
    assert worker.health() == "ok"
    store.close()
    reopened = Store(tmp_path / "state.db")
    assert reopened.count_runs() == 50
    reopened.close()
