"""The daemon over a faulty state database (#22.4, #22.5): another process's write lock does not
stall or kill it, and bad rows or a damaged page at start-up are quarantined while it comes up."""

from __future__ import annotations

import sqlite3
import subprocess
import sys
import time
from typing import Any

import pytest

from hdeem_watch.daemon import protocol
from hdeem_watch.daemon.store import Store

FAST = {"HDEEM_WATCH_MODEL_MAX_REQUESTS": "100000", "HDEEM_WATCH_REPUBLISH_S": "0.5",
        "HDEEM_WATCH_QUIET_WINDOW_S": "1"}

LOCKER = """
import sqlite3, sys
db = sqlite3.connect(sys.argv[1], isolation_level=None)
db.execute("BEGIN IMMEDIATE")
db.execute("INSERT OR REPLACE INTO meta (key, value) VALUES ('locker', 'x')")
print("locked", flush=True)
sys.stdin.readline()
db.execute("ROLLBACK")
"""


@pytest.mark.slow
def test_a_foreign_write_lock_neither_stalls_nor_kills_the_daemon(daemon_factory: Any, receive: Any) -> None:
    """Runs and quiet-period baselines while another process holds the write lock: replies come, the stream
    flows, nothing is lost once the lock goes (old code: the loop blocked 5 s, then 'database is locked' killed it)."""
    d = daemon_factory("--speed", "20", **FAST).start()
    sub = d.subscriber(protocol.subscription(d.node, "samples") + b"DDR_AB")
    time.sleep(0.3)
    locker = subprocess.Popen([sys.executable, "-c", LOCKER, str(d.state_dir / "state.db")], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True)
    stopped = []
    try:
        assert locker.stdout is not None and locker.stdout.readline().strip() == "locked"
        receive(sub, 0.1)
        with d.client(timeout_s=60.0) as client:
            for kernel in ("idle", "triad"):
                started = client.call("run.start", {"kernel": kernel, "elements": 0 if kernel == "idle" else 2**20})
                time.sleep(0.5)
                stopped.append(client.call("run.stop", {"run_id": started["run_id"]}))
            deadline = time.monotonic() + 15.0  # quiet periods are looked for and saved meanwhile
            while "database is locked" not in d.stderr() and time.monotonic() < deadline:
                time.sleep(0.05)
            assert [r["run_id"] for r in client.call("runs.list", {"limit": 2})["runs"]] == \
                [stopped[1]["run_id"], stopped[0]["run_id"]]
        batches = receive(sub, 0.5)
        assert d.proc.poll() is None, d.stderr()[-3000:]
    finally:
        assert locker.stdin is not None
        locker.stdin.write("\n")
        locker.stdin.close()
        locker.wait(timeout=10)
    seqs = [m.seq for m in batches]
    assert len(seqs) >= 5 and seqs == list(range(seqs[0], seqs[0] + len(seqs)))
    assert all(r["state"] == "done" and r["dram_energy_j"] for r in stopped)
    assert "database is locked" in d.stderr()
    assert d.terminate() == 0, d.stderr()[-3000:]
    store = Store(d.state_dir / "state.db")
    assert {r["run_id"] for r in store.list_runs()} >= {r["run_id"] for r in stopped}
    store.close()


@pytest.mark.slow
def test_bad_rows_and_a_damaged_page_at_start_are_quarantined_and_the_daemon_comes_up(daemon_factory: Any) -> None:
    """Bad JSON in each table and a damaged page: the daemon starts, lists the readable runs, logs the findings."""
    d = daemon_factory("--speed", "20", **FAST)
    path = d.state_dir / "state.db"
    store = Store(path)
    for i in range(1, 201):
        store.save_run({"run_id": f"r{i}", "kernel": "triad", "state": "done", "t_start_ns": i, "pad": "y" * 400})
    store.save_run({"run_id": "r201", "kernel": "triad", "state": "running", "t_start_ns": 201})
    store.save_baseline("DDR_AB", {"channel": "DDR_AB", "power_w": 2.0, "t_ns": 1})
    store.save_calibration(5, {"observations": []}, {"n_runs": 1}, "r1")
    store.close()
    db = sqlite3.connect(path, isolation_level=None)
    db.execute("UPDATE runs SET record = '{broken' WHERE run_id IN ('r7', 'r201')")
    db.execute("UPDATE fits SET fit = 'nope'")
    db.execute("UPDATE calibrator SET state = '{'")
    db.execute("UPDATE baselines SET record = '['")
    db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    page_size, pages = db.execute("PRAGMA page_size").fetchone()[0], db.execute("PRAGMA page_count").fetchone()[0]
    db.close()
    with open(path, "r+b") as f:
        f.seek(page_size * (pages // 2))
        f.write(b"\x5a" * page_size)
    d.start()  # old code: a traceback and exit 1 (a restart loop under systemd)
    with d.client(timeout_s=30.0) as client:
        runs = client.call("runs.list", {"limit": 1000})["runs"]
        assert client.call("calib.get") is not None
        new = client.call("run.start", {"kernel": "idle"})["run_id"]
        client.call("run.stop", {"run_id": new, "abort": True})
    ids = {r["run_id"] for r in runs}
    assert 150 <= len(ids) < 200 and "r7" not in ids and "r200" in ids
    assert int(new[1:]) == 202  # run ids never reused, even the quarantined r201's
    err = d.stderr()
    assert "state database:" in err and "damaged" in err and "Traceback" not in err
    assert list(d.state_dir.glob("state.db.corrupt-*"))
