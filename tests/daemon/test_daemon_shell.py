"""The daemon's shell with real sockets: what the pure core cannot show (the lock, the loop under a full disk)."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from hdeem_watch.config import DaemonSettings
from hdeem_watch.daemon.shell.service import Daemon
from hdeem_watch.errors import InputError
from hdeem_watch.sources.sim import SimSource
from hdeem_watch.wire.client import ControlClient


def _settings(tmp_path: Path, **extra: Any) -> DaemonSettings:
    return DaemonSettings(pub=f"ipc://{tmp_path}/p.sock", control=f"ipc://{tmp_path}/c.sock",
                          state_dir=str(tmp_path / "s"), node="n", speed=20.0, heartbeat_s=0.2,
                          model_max_requests=100_000, **extra)


@pytest.fixture
def running(tmp_path: Path) -> Iterator[Daemon]:
    daemon = Daemon(_settings(tmp_path), source=SimSource(seed=3, speed=20.0))
    daemon.start()
    loop = threading.Thread(target=daemon.run)
    loop.start()
    try:
        yield daemon
    finally:
        daemon.request_stop()
        loop.join()
        daemon.close()


def test_the_lock_is_the_daemons_alone(tmp_path: Path) -> None:
    """daemon.lock is 0600 (a group member could otherwise hold it and keep the service down), also
    when an older daemon left it 0660; a second daemon on the state directory is refused."""
    state = tmp_path / "s"
    state.mkdir()
    (state / "daemon.lock").touch(mode=0o660)
    os.chmod(state / "daemon.lock", 0o660)
    first = Daemon(_settings(tmp_path), source=SimSource(seed=1, speed=20.0))
    first.start()
    try:
        assert (state / "daemon.lock").stat().st_mode & 0o777 == 0o600
        other = tmp_path / "other"
        other.mkdir()
        second = Daemon(DaemonSettings(pub=f"ipc://{other}/p.sock", control=f"ipc://{other}/c.sock",
                                       state_dir=str(state), node="n"), source=SimSource(seed=2))
        with pytest.raises(InputError, match="another hdeem-watch daemon"):
            second.start()
    finally:
        first.close()


@pytest.mark.slow
def test_a_full_disk_degrades_the_daemon_and_loses_nothing(running: Daemon) -> None:
    """With the database full (SQLite's own 'database or disk is full'), a run still replies with its
    record, the status says the store is degraded, the loop and the stream go on; once there is room
    the kept writes are made and the status is ok again."""
    store = running.store
    worker = running.store_worker
    assert store is not None and worker is not None
    done = threading.Event()
    # SQLite's own "database or disk is full": the store's writer connection may not grow the file
    # (PRAGMA max_page_count on that very connection, set before each write while "full").
    full = {"on": False}
    writer = store._writer
    write = writer._apply

    def capped(db: Any, op: Any) -> None:
        pages = db.execute("PRAGMA page_count").fetchone()[0] if full["on"] else 1 << 30
        db.execute(f"PRAGMA max_page_count = {pages}")
        write(db, op)

    writer._apply = capped

    def limit(pages: int | None) -> None:
        full["on"] = pages is None

    with ControlClient(running.control_endpoint, timeout_s=30.0) as client:
        limit(None)  # full: not one page more
        run_id = client.call("run.start", {"kernel": "triad", "elements": 1 << 22, "metadata": {"pad": "x" * 20_000}})["run_id"]
        time.sleep(0.1)
        record = client.call("run.stop", {"run_id": run_id})
        degraded = client.call("status")
        limit(1 << 30)  # room again: the store's writer retries and writes what it kept
        deadline = time.monotonic() + 20
        while (status := client.call("status"))["store"]["health"] != "ok" and time.monotonic() < deadline:
            time.sleep(0.1)
    assert record["state"] == "done" and record["dram_energy_j"] > 0
    assert degraded["store"]["health"].startswith("degraded:") and "full" in degraded["store"]["health"]
    assert status["store"]["health"] == "ok" and status["channels"]["DDR_AB"]["samples"] > 0
    stored: dict[str, Any] = {}
    done.clear()
    worker.read(lambda s: s.get_run(run_id), lambda r: (stored.update(r or {}), done.set()), lambda _e: done.set())
    deadline = time.monotonic() + 10
    while not done.is_set() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert stored.get("state") == "done" and stored.get("fit") == record["fit"]
