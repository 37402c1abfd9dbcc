"""The daemon over a faulty state database (#22.4, #22.5): another process's write lock does not
stall or kill it, and bad rows or a damaged page at start-up are quarantined while it comes up."""

from __future__ import annotations

import os
import sqlite3
import subprocess
import sys
import time
from typing import Any

import pytest

from hdeem_watch.daemon.store.database import Store
from hdeem_watch.wire import protocol

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


def _seed_every_table(path: Any) -> None:
    """A state database with a usable row and a row of valid JSON the daemon cannot use in each table."""
    from hdeem_watch.daemon.jobs.records import parse_job_args
    from hdeem_watch.job_record import JobRecord

    store = Store(path)
    store.save_run({"run_id": "r1", "kernel": "triad", "state": "done", "t_start_ns": 1})
    store.save_run({"run_id": "r2", "kernel": "triad", "state": "running", "t_start_ns": 2})
    fit = {"n_runs": 1, "error": {"after": 0.1}, "currents": {"idd0": {"calibrated": 0.05}}}
    store.save_calibration(5, {"observations": []}, fit, "r1")
    store.save_calibration(6, {"observations": []}, fit, "r1")
    for channel, origin in (("DDR_AB", "measured"), ("DDR_CD", "guessed")):
        store.save_baseline(channel, {"power_w": 2.0, "spread_w": 0.1, "n": 100, "t_ns": 1, "origin": origin})
    store.save_alarm(7, "r1", {"group": "DDR_AB", "current": "idd0", "kind": "cusum"})
    store.save_alarm(8, "r1", {"current": "idd0"})
    for job_id in ("41", "42"):
        store.save_job(JobRecord.start(parse_job_args({"job_id": job_id, "uid": 1000, "user": "alice"}), node="testnode",
                                       t_wall_ns=int(job_id)).to_dict())
    store.close()
    db = sqlite3.connect(path, isolation_level=None)
    db.execute("""UPDATE fits SET fit = '{"currents": [1, 2]}' WHERE t_ns = 6""")  # the probe's row
    db.execute("""UPDATE runs SET record = '{"run_id": "r2", "state": "running", "t_start_ns": "soon"}' WHERE run_id = 'r2'""")
    db.execute("""UPDATE calibrator SET state = '{"observations": "x"}'""")
    db.execute("""UPDATE jobs SET record = json_set(record, '$.segments', 5) WHERE job_id = '42'""")
    db.close()


@pytest.mark.slow
def test_a_row_of_the_wrong_shape_in_any_table_is_quarantined_and_the_daemon_starts(daemon_factory: Any) -> None:
    """Valid JSON the daemon cannot use in fits, runs, calibrator, baselines, alarms and jobs (once:
    ``update fits set fit='{"currents": [1,2]}'`` gave an AttributeError and exit 1 at every start):
    each row goes to the quarantine table with the reason, the daemon starts with the rest."""
    d = daemon_factory(**FAST)
    path = d.state_dir / "state.db"
    d.state_dir.mkdir(parents=True)
    _seed_every_table(path)
    d.start()
    with d.client(timeout_s=30.0) as client:
        deadline = time.monotonic() + 30
        while client.call("calib.get").get("loading"):
            assert time.monotonic() < deadline
            time.sleep(0.1)
        calib = client.call("calib.get")
        runs = client.call("runs.list")["runs"]
        jobs = client.call("status")["jobs"]
        baselines = client.call("baseline.get")["channels"]
    assert [h["t_ns"] for h in calib["history"]] == [5]
    assert [r["run_id"] for r in runs] == ["r1"]
    assert [j["job_id"] for j in jobs] == ["41"]
    assert baselines["DDR_AB"]["origin"] == "measured" and baselines.get("DDR_CD", {}).get("origin") != "guessed"
    assert d.terminate() == 0, d.stderr()[-3000:]
    err = d.stderr()
    assert "Traceback" not in err and err.count("(moved to table quarantine)") == 6, err[-3000:]
    db = sqlite3.connect(path)
    moved = db.execute("SELECT source, reason FROM quarantine").fetchall()
    db.close()
    assert sorted(source for source, _reason in moved) == ["alarms", "baselines", "calibrator", "fits", "jobs", "runs"]
    assert all(reason.startswith("unusable: ") for _source, reason in moved)


@pytest.fixture
def small_disk(tmp_path: Any) -> Any:
    """A real file system of 16 MiB (tmpfs) to fill up: ``(mount point, fill, free)``."""
    mount = tmp_path / "d" / "state"
    mount.mkdir(parents=True)
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=16m,mode=0750", "tmpfs", str(mount)], check=True)
    filler = mount / "filler"

    def fill() -> None:
        with open(filler, "ab") as out:
            try:
                while True:
                    out.write(b"\0" * 65536)
                    out.flush()
            except OSError:
                pass

    try:
        yield mount, fill, lambda: filler.unlink()
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


@pytest.mark.slow
def test_run_ids_given_on_a_full_disk_are_never_given_again_after_kill_9(daemon_factory: Any, small_disk: Any) -> None:
    """The probe's path on a real full file system: runs acknowledged while the database cannot be
    written say ``"stored": false`` (once: nothing said so); kill -9, space freed, restart: the
    next run id is new (once: the lost runs' ids were given again)."""
    _mount, fill, free = small_disk
    d = daemon_factory("--speed", "20", **FAST)
    d.start()
    with d.client(timeout_s=30.0) as client:
        first = client.call("run.start", {"kernel": "idle"})
        assert first["stored"] is True
        assert client.call("run.stop", {"run_id": first["run_id"], "abort": True})["stored"] is True
        fill()
        given = []
        for _ in range(2):
            started = client.call("run.start", {"kernel": "idle"})
            stopped = client.call("run.stop", {"run_id": started["run_id"], "abort": True})
            assert started["stored"] is False and stopped["stored"] is False, (started, stopped)
            given.append(started["run_id"])
        assert client.call("status")["store"]["health"].startswith("degraded")
    d.kill9()
    free()
    d.start()
    with d.client(timeout_s=30.0) as client:
        lost = [r["run_id"] for r in client.call("runs.list")["runs"]]
        new = client.call("run.start", {"kernel": "idle"})
        client.call("run.stop", {"run_id": new["run_id"], "abort": True})
    assert lost == [first["run_id"]]  # the rows of the runs acknowledged on the full disk died with the daemon
    seq = [int(run_id[1:]) for run_id in (first["run_id"], *given)]
    assert seq == [1, 2, 3] and new["run_id"] == "r4", (given, new)
    assert new["stored"] is True


@pytest.mark.slow
@pytest.mark.parametrize("umask", [0o022, 0o000])
def test_state_files_are_private_whatever_the_umask(daemon_factory: Any, umask: int) -> None:
    """Run by hand with ``umask 022`` (or none at all), the daemon's state files are still its own:
    state.db and its -wal and -shm, the run id mark and the lock at most 0640 (once: state.db 0644)."""
    d = daemon_factory()
    old = os.umask(umask)
    try:
        d.start()
    finally:
        os.umask(old)
    with d.client() as client:
        client.call("job.start", {"job_id": "5"})  # a write: the -wal and -shm exist
    files = {p.name: p.stat().st_mode & 0o7777 for p in d.state_dir.iterdir() if p.is_file()}
    assert {"state.db", "state.db-wal", "state.db-shm", "state.db.run-ids", "daemon.lock"} <= set(files), files
    assert all(mode & 0o137 == 0 for mode in files.values()), {k: oct(v) for k, v in files.items()}
    assert d.terminate() == 0


@pytest.fixture
def ext4_state(tmp_path: Any) -> Any:
    """The state directory on a real ext4 file system (a loop device) mounted ``errors=remount-ro``;
    yields a function that makes the kernel remount it read-only, as after an I/O error (ext4's
    ``trigger_fs_error``, documented in the kernel's Documentation/ABI/testing/sysfs-fs-ext4)."""
    image, mount = tmp_path / "fs.img", tmp_path / "d" / "state"
    mount.mkdir(parents=True)
    with open(image, "wb") as out:
        out.truncate(32 << 20)
    subprocess.run(["mkfs.ext4", "-q", "-F", str(image)], check=True)
    subprocess.run(["mount", "-o", "loop,errors=remount-ro", str(image), str(mount)], check=True)
    device = subprocess.run(["findmnt", "-no", "SOURCE", str(mount)], capture_output=True, text=True,
                            check=True).stdout.strip()

    def remount_read_only() -> None:
        with open(f"/sys/fs/ext4/{os.path.basename(device)}/trigger_fs_error", "w") as trigger:
            trigger.write("hdeem-watch test: a disk error")
        options = subprocess.run(["findmnt", "-no", "OPTIONS", str(mount)], capture_output=True, text=True).stdout
        assert "ro" in options.split(",") or "emergency_ro" in options, options

    try:
        yield remount_read_only
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


@pytest.mark.slow
def test_a_read_only_remount_while_running_degrades_and_acks_say_not_stored(daemon_factory: Any, ext4_state: Any) -> None:
    """The kernel remounts the state directory's file system read-only under the running daemon:
    the status turns ``degraded`` at once (once: ``ok``) and the acknowledgements of job.start,
    run.start and run.stop say ``"stored": false`` (once: acknowledged like any other); the
    daemon goes on measuring."""
    d = daemon_factory("--speed", "20", **FAST)
    d.start()
    with d.client(timeout_s=30.0) as client:
        assert client.call("status")["store"]["health"] == "ok"
        assert client.call("job.start", {"job_id": "7"})["stored"] is True
        ext4_state()
        health = client.call("status")["store"]["health"]
        assert health.startswith("degraded") and "read-only" in health.lower(), health
        assert client.call("job.start", {"job_id": "8"})["stored"] is False
        run = client.call("run.start", {"kernel": "idle"})
        stopped = client.call("run.stop", {"run_id": run["run_id"], "abort": True})
        assert run["stored"] is False and stopped["stored"] is False and stopped["state"] == "aborted"
        assert client.call("job.get", {"job_id": "8"})["state"] == "running"  # kept in memory
        assert client.call("status")["store"]["health"].startswith("degraded")
    assert "Traceback" not in d.stderr()
