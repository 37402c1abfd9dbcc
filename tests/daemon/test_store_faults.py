"""The state database under faults (#22.4, #22.5): a full disk, another process's write lock,
bad JSON in every table and a damaged page. Saves never raise and never block for long, what
was saved stays visible and is written once the disk allows, and start-up quarantines instead
of crashing."""

from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from hdeem_watch.daemon.store.database import Store, StoreError


def _run(i: int, pad: int = 0, state: str = "done", kernel: str = "triad") -> dict[str, Any]:
    return {"run_id": f"r{i}", "kernel": kernel, "state": state, "t_start_ns": i, "pad": "x" * pad,
            "fit": {"runs": list(range(50))}, "model": {"datasheet_j": 1.0, "observation": [1, 2, 3]}}


FULL_DISK = r"""
import json, resource, sys, time
from pathlib import Path
from hdeem_watch.daemon.store.database import Store
path = Path(sys.argv[1])
store = Store(path, retry_min_s=0.05, retry_max_s=0.1)
store.save_run({"run_id": "r1", "kernel": "triad", "state": "done", "t_start_ns": 1})
wal = Path(str(path) + "-wal").stat().st_size
# The file system is "full": no file of this process may grow (EFBIG, as ENOSPC would).
resource.setrlimit(resource.RLIMIT_FSIZE, (wal, resource.RLIM_INFINITY))
t0 = time.monotonic()
for i in range(2, 6):
    store.save_run({"run_id": f"r{i}", "kernel": "triad", "state": "done", "t_start_ns": i, "pad": "x" * 200_000})
store.save_baseline("DDR_AB", {"power_w": 2.5, "t_ns": 9})
store.save_calibration(10, {"observations": [1]}, {"n_runs": 5}, "r5")
blocked_s = time.monotonic() - t0
time.sleep(0.5)
during = {"health": store.health(), "runs": [r["run_id"] for r in store.list_runs()], "count": store.count_runs(),
          "get": store.get_run("r5") is not None, "baseline": store.load_baselines(),
          "calibrator": store.load_calibrator(), "fits": [f for _t, _r, f in store.fit_history()],
          "next": store.next_run_id(), "blocked_s": blocked_s}
resource.setrlimit(resource.RLIMIT_FSIZE, (resource.RLIM_INFINITY, resource.RLIM_INFINITY))
flushed = store.flush(10.0)
after = {"health": store.health(), "flushed": flushed}
store.close()
print(json.dumps({"during": during, "after": after}))
"""


@pytest.mark.slow
def test_a_full_disk_degrades_and_loses_nothing(tmp_path: Path) -> None:
    """Disk full: saves return at once, reads see them, health says why; once space is back all is written."""
    path = tmp_path / "state.db"
    out = subprocess.run([sys.executable, "-c", FULL_DISK, str(path)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr[-2000:]
    result = json.loads(out.stdout)
    during, after = result["during"], result["after"]
    assert during["health"].startswith("degraded: state database not writable"), during["health"]
    assert during["runs"] == ["r5", "r4", "r3", "r2", "r1"] and during["count"] == 5 and during["get"]
    assert during["baseline"] == {"DDR_AB": {"power_w": 2.5, "t_ns": 9}}
    assert during["calibrator"] == {"observations": [1]} and during["fits"] == [{"n_runs": 5}]
    assert during["next"] == "r6" and during["blocked_s"] < 2.0
    assert after == {"health": "ok", "flushed": True}
    store = Store(path)  # a new daemon sees everything that was acknowledged
    assert [r["run_id"] for r in store.list_runs()] == ["r5", "r4", "r3", "r2", "r1"]
    assert store.load_baselines()["DDR_AB"]["power_w"] == 2.5 and store.load_calibrator() == {"observations": [1]}
    store.close()


LOCKER = """
import sqlite3, sys, time
db = sqlite3.connect(sys.argv[1], isolation_level=None)
db.execute("BEGIN IMMEDIATE")
db.execute("INSERT INTO meta (key, value) VALUES ('locker', 'x')")
print("locked", flush=True)
sys.stdin.readline()
db.execute("ROLLBACK")
"""


@pytest.mark.slow
def test_another_process_holding_the_write_lock_never_blocks_the_caller(tmp_path: Path) -> None:
    """A write lock held by another process: saves return within the sync wait, reads work, writes follow the lock."""
    path = tmp_path / "state.db"
    store = Store(path, retry_min_s=0.05, retry_max_s=0.2)
    store.save_run(_run(1))
    locker = subprocess.Popen([sys.executable, "-c", LOCKER, str(path)], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert locker.stdout is not None and locker.stdout.readline().strip() == "locked"
        t0 = time.monotonic()
        for i in range(2, 12):
            store.save_run(_run(i))
            store.save_baseline("DDR_AB", {"power_w": float(i), "t_ns": i})
        # One sync wait (0.25 s) for the first save, none after it: old code waited 5 s per save,
        # then raised "database is locked" into the poll loop.
        assert time.monotonic() - t0 < 1.0
        deadline = time.monotonic() + 10.0  # until the writer's own busy timeout (2 s) has run out once
        while not store.health().startswith("degraded") and time.monotonic() < deadline:
            time.sleep(0.05)
        assert store.health().startswith("degraded: state database not writable (database is locked)")
        assert [r["run_id"] for r in store.list_runs(limit=3)] == ["r11", "r10", "r9"]
        assert store.load_baselines()["DDR_AB"]["power_w"] == 11.0
    finally:
        assert locker.stdin is not None
        locker.stdin.write("\n")
        locker.stdin.close()
        locker.wait(timeout=10)
    assert store.flush(15.0) and store.health() == "ok"
    store.close()
    check = sqlite3.connect(path)
    assert check.execute("SELECT COUNT(*) FROM runs").fetchone()[0] == 11
    check.close()


def test_summaries_pages_and_full_records(tmp_path: Path) -> None:
    """list_runs gives summaries (no refit, no calibration row) unless full, and pages with before."""
    store = Store(tmp_path / "state.db")
    for i in range(1, 8):
        store.save_run(_run(i, kernel="idle" if i % 2 else "triad"))
    store.flush()
    store.save_run(_run(8))  # one still in memory is listed the same way
    summaries = store.list_runs(limit=3)
    assert [r["run_id"] for r in summaries] == ["r8", "r7", "r6"]
    # The refit reduced to its run count and error (the same summary whether read from disk or memory).
    assert all(r["fit"] == {"n_runs": None, "error": None} and r["model"] == {"datasheet_j": 1.0}
               for r in summaries)
    full = store.list_runs(limit=2, full=True)
    assert full[0]["fit"] == {"runs": list(range(50))} and full[1]["model"]["observation"] == [1, 2, 3]
    assert [r["run_id"] for r in store.list_runs(limit=3, before="r6")] == ["r5", "r4", "r3"]
    assert [r["run_id"] for r in store.list_runs(limit=10, before=5, kernel="idle")] == ["r3", "r1"]
    store.close()


def _seed(path: Path) -> None:
    store = Store(path)
    for i in range(1, 6):
        store.save_run(_run(i))
    store.save_run(_run(6, state="running"))
    store.save_baseline("DDR_AB", {"power_w": 2.0, "t_ns": 1})
    store.save_baseline("DDR_CD", {"power_w": 3.0, "t_ns": 1})
    store.save_calibration(5, {"observations": [1]}, {"n_runs": 1}, "r1")
    store.save_calibration(6, {"observations": [1, 2]}, {"n_runs": 2}, "r2")
    store.close()


def test_bad_json_in_every_table_is_quarantined_at_start(tmp_path: Path) -> None:
    """Malformed JSON in runs (also a running one), fits, calibrator and baselines: quarantined, the rest loads."""
    path = tmp_path / "state.db"
    _seed(path)
    db = sqlite3.connect(path, isolation_level=None)
    db.execute("UPDATE runs SET record = '{\"run_id\": \"r2\", oops' WHERE run_id = 'r2'")
    db.execute("UPDATE runs SET record = '[1, 2]' WHERE run_id = 'r6'")  # the running run: JSON, not an object
    db.execute("UPDATE fits SET fit = '{broken' WHERE run_id = 'r2'")
    db.execute("UPDATE calibrator SET state = 'NaN-garbage'")
    db.execute("UPDATE baselines SET record = '' WHERE channel = 'DDR_CD'")
    db.close()
    store = Store(path)  # old code: json.loads raised out of load_state/close_interrupted_runs → exit 1
    assert len(store.quarantined) == 5 and all("moved to table quarantine" in q for q in store.quarantined)
    assert store.close_interrupted_runs(99) == 0
    assert [r["run_id"] for r in store.list_runs()] == ["r5", "r4", "r3", "r1"]
    assert store.get_run("r2") is None and store.count_runs() == 4 and store.next_run_id() == "r7"
    assert [f for _t, _r, f in store.fit_history()] == [{"n_runs": 1}]
    assert store.load_calibrator() is None and list(store.load_baselines()) == ["DDR_AB"]
    store.close()
    db = sqlite3.connect(path)
    kept = db.execute("SELECT source, row_key, content FROM quarantine ORDER BY id").fetchall()
    db.close()
    assert ("runs", "r2", '{"run_id": "r2", oops') in kept and len(kept) == 5  # nothing deleted: kept aside


def test_rows_the_quarantine_could_not_move_are_skipped_by_the_readers(tmp_path: Path) -> None:
    """Bad rows written after start-up (or left because the file was locked) never reach a loader."""
    path = tmp_path / "state.db"
    _seed(path)
    store = Store(path)
    db = sqlite3.connect(path, isolation_level=None)
    db.execute("UPDATE runs SET record = 'x' WHERE run_id = 'r3'")
    db.execute("UPDATE baselines SET record = '{' WHERE channel = 'DDR_AB'")
    db.close()
    assert [r["run_id"] for r in store.list_runs()] == ["r6", "r5", "r4", "r2", "r1"]
    assert store.get_run("r3") is None and "DDR_AB" not in store.load_baselines()
    store.close()


def test_a_damaged_page_is_salvaged_and_the_rest_kept(tmp_path: Path) -> None:
    """A page of runs overwritten with garbage: the readable runs are kept in a fresh file, the damaged one kept aside."""
    path = tmp_path / "state.db"
    store = Store(path)
    for i in range(1, 301):
        store.save_run(_run(i, pad=300))
    store.close()
    db = sqlite3.connect(path)
    db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    page_size = db.execute("PRAGMA page_size").fetchone()[0]
    pages = db.execute("PRAGMA page_count").fetchone()[0]
    db.close()
    with open(path, "r+b") as f:
        f.seek(page_size * (pages // 2))
        f.write(b"\xa5" * page_size)
    with pytest.raises(sqlite3.DatabaseError):  # what the old code's first query met
        sqlite3.connect(path).execute("SELECT record FROM runs").fetchall()
    store = Store(path)
    assert store.quarantined and "damaged" in store.quarantined[0]
    kept = store.list_runs(limit=1000)
    assert 250 <= len(kept) < 300 and kept[0]["run_id"] == "r300"
    assert store.count_runs() == len(kept) and store.health() == "ok"
    store.save_run(_run(301))
    assert store.flush() and store.get_run("r301") is not None
    store.close()
    assert list(tmp_path.glob("state.db.corrupt-*"))


def test_a_file_that_is_no_database_is_one_store_error(tmp_path: Path) -> None:
    """Nothing to salvage (not an SQLite file at all): StoreError (the daemon's one line and exit 2)."""
    path = tmp_path / "state.db"
    path.write_bytes(b"\x00garbage" * 1000)
    with pytest.raises(StoreError, match="cannot use the state database"):
        Store(path)


def test_a_garbled_schema_version_is_one_store_error(tmp_path: Path) -> None:
    """meta.schema_version that is no number: StoreError (old: ValueError traceback)."""
    path = tmp_path / "state.db"
    Store(path).close()
    db = sqlite3.connect(path, isolation_level=None)
    db.execute("UPDATE meta SET value = 'one' WHERE key = 'schema_version'")
    db.close()
    with pytest.raises(StoreError, match="schema_version = 'one'"):
        Store(path)



def test_a_database_cut_to_half_its_size_keeps_what_is_left(tmp_path: Path) -> None:
    """A state.db truncated to half its size (once: every table "unreadable", 0 rows kept): the rows
    in the pages that remain are salvaged into a fresh file, the cut file kept aside."""
    path = tmp_path / "state.db"
    store = Store(path)
    for i in range(1, 301):
        store.save_run(_run(i, pad=300))
    store.save_baseline("DDR_AB", {"power_w": 2.0, "t_ns": 1})
    store.close()
    db = sqlite3.connect(path)
    db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    db.close()
    with open(path, "r+b") as f:
        f.truncate(path.stat().st_size // 2)
    store = Store(path)
    kept = [r["run_id"] for r in store.list_runs(limit=1000)]
    assert store.quarantined[0].startswith("state.db: damaged") and "\n" not in store.quarantined[0]
    assert len(kept) >= 50 and "r1" in kept and "r300" not in kept, len(kept)
    assert store.load_baselines()["DDR_AB"]["power_w"] == 2.0
    store.save_run(_run(301))
    assert store.flush() and store.get_run("r301") is not None and store.health() == "ok"
    store.close()
    assert list(tmp_path.glob("state.db.corrupt-*"))
