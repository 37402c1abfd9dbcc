"""The daemon's persistent state: runs, calibration fits and calibrator state, baselines, jobs.

One SQLite file (``state.db``) in the state directory, in WAL mode with ``synchronous=FULL``. The
schema is versioned (table ``meta``, key ``schema_version``); a newer schema than this code knows
is refused rather than misread. Records are stored as JSON text (NaN as null) beside the columns
used for lookups.

The daemon's loop never waits for the disk and never dies of it:

* Writes return at once. They are serialised on the caller's thread (a snapshot) and written by a
  :class:`~hdeem_watch.daemon.store.writer.BackgroundWriter` thread in order, each in one committed
  transaction. While the disk is full, read-only or locked by another process, the writes wait in
  memory and are retried; :meth:`Store.health` says ``degraded: <reason>`` meanwhile. Whatever was
  saved is visible to every read at once, written or not.
* Reads merge what is still waiting with what is on disk; a read that fails degrades the health
  and returns what memory holds instead of raising.
* At start-up a damaged file is salvaged and rows with bad JSON are quarantined
  (:mod:`~hdeem_watch.daemon.store.repair`), listed in :attr:`Store.quarantined`. Only a file that
  cannot be opened or created at all is a :class:`StoreError`.

Example:
    >>> import tempfile, pathlib
    >>> store = Store(pathlib.Path(tempfile.mkdtemp()) / "state.db")
    >>> run_id = store.next_run_id()
    >>> _ = store.save_run({"run_id": run_id, "kernel": "triad", "state": "running", "t_start_ns": 1})
    >>> [r["kernel"] for r in store.list_runs()], store.health()
    (['triad'], 'ok')
    >>> store.close()
"""

from __future__ import annotations

import itertools
import json
import logging
import os
import sqlite3
import threading
import time
from collections.abc import Callable, Hashable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hdeem_watch.daemon.book.runs import run_summary
from hdeem_watch.daemon.store.jobs import JobRow, job_matches, job_query, job_row
from hdeem_watch.daemon.store.repair import (
    create_private,
    quarantine_bad_rows,
    quarantine_unusable_rows,
    salvage_if_corrupt,
)
from hdeem_watch.daemon.store.run_ids import RunIdMark
from hdeem_watch.daemon.store.writer import BackgroundWriter
from hdeem_watch.state_schema import (
    INSERT_JOB,
    INSERT_RUN,
    SCHEMA,
    SCHEMA_VERSION,
    has_every_table,
    schema_version,
)
from hdeem_watch.wire.protocol import jsonable

log = logging.getLogger("hdeem_watch.daemon.store.database")

#: Fields left out of a run summary (``list_runs(full=False)``): the refit and the model's
#: calibration row, which grow with the number of runs (tens of KB per record).
#: A summary read in SQL: the record without the parts that grow with the calibration, and the two
#: figures of the fit a summary keeps (:func:`~hdeem_watch.daemon.book.runs.run_summary` shapes the rest).
_SUMMARY_SQL = ("json_remove(record, '$.fit', '$.model.observation'), json_type(record, '$.fit'), "
                "json_extract(record, '$.fit.n_runs'), json_type(record, '$.fit.error'), "
                "json_extract(record, '$.fit.error.after')")
#: How long a read waits for a lock held by another process before it gives up (s).
READ_TIMEOUT_S = 0.05
#: How long a save waits for its own write while the database is healthy (s): a record is then
#: on disk before the daemon acknowledges it (a ``kill -9`` loses nothing acknowledged). While
#: writes fail, saves do not wait at all.
SYNC_WAIT_S = 0.25
#: How long :meth:`Store.close` keeps trying to write what is pending (s).
CLOSE_FLUSH_S = 5.0


class StoreError(RuntimeError):
    """The state database cannot be used at all (newer schema, not a database, cannot be created)."""


def _dumps(value: Any) -> str:
    """Strict JSON text (NaN as null); a ``str`` is taken as JSON text already (serialised elsewhere)."""
    if isinstance(value, str):
        return value
    return json.dumps(jsonable(value), separators=(",", ":"), allow_nan=False)


def _summary_from_sql(text: str, fit_type: str | None, n_runs: Any, error_type: str | None,
                      error_after: Any) -> dict[str, Any] | None:
    """A :func:`run_summary` from the columns of :data:`_SUMMARY_SQL` (the fit never parsed)."""
    record = _loads(text)
    if not isinstance(record, dict):
        return None
    if fit_type == "object":
        record["fit"] = {"n_runs": n_runs}
        if error_type == "object":
            record["fit"]["error"] = {"after": error_after}
    elif fit_type is not None:
        record["fit"] = None
    return run_summary(record)


def _loads(text: str | None) -> Any:
    try:
        return None if text is None else json.loads(text)
    except ValueError:
        return None


@dataclass(frozen=True)
class _RunRow:
    seq: int
    kernel: str
    state: str
    t_start_ns: int
    record: str
    summary: str


@dataclass(frozen=True)
class _CalibOp:
    t_ns: int
    state: str | None  # None: calib.reset (the calibrator is forgotten)
    fit: str | None  # None with a state: the state alone (a group's reset), no history entry
    run_id: str | None
    quarantine: str | None = None  # the stored state cannot be restored: moved aside for this reason


class Store:
    """SQLite state of one daemon (open one per state directory; the daemon's lock file ensures it).

    Args:
        path: the database file; its directory is created (mode 0750) if missing.
        clock: wall clock in ns (quarantine and salvage stamps).
        retry_min_s: first pause after a failed write (doubling up to ``retry_max_s``).
        retry_max_s: longest pause between two tries of a failed write.
        sync_wait_s: how long a save waits for its write while the database is healthy
            (:data:`SYNC_WAIT_S`; 0 = never wait).
        row_checks: per table, how the rows the daemon loads at start are checked beyond their JSON
            (:data:`hdeem_watch.daemon.store.checks.ROW_CHECKS`); a row that fails is quarantined.

    Attributes:
        quarantined: one line per damaged page or bad row found at start-up (empty when sound).

    Raises:
        StoreError: the file is not a database, has a newer schema, or cannot be created.
    """

    def __init__(self, path: str | Path, *, clock: Callable[[], int] = time.time_ns, retry_min_s: float = 0.2,
                 retry_max_s: float = 5.0, sync_wait_s: float = SYNC_WAIT_S,
                 row_checks: Mapping[str, Any] | None = None) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True, mode=0o750)
        try:
            self.quarantined = salvage_if_corrupt(self.path, t_ns=clock())
            create_private(self.path)  # 0600 whatever the umask; its -wal and -shm take its mode
            self._db = self._connect(READ_TIMEOUT_S)
            version = self._schema_version()
            if version is not None and version > SCHEMA_VERSION:
                raise StoreError(f"{self.path}: schema version {version} is newer than this daemon's {SCHEMA_VERSION}")
            if version is None or not has_every_table(self._db):
                self._db.execute("PRAGMA busy_timeout = 5000")  # creating it: nothing to save otherwise
                self._db.executescript(SCHEMA)
                self._db.execute("INSERT OR IGNORE INTO meta (key, value) VALUES ('schema_version', ?)",
                                 (str(SCHEMA_VERSION),))
                self._db.execute(f"PRAGMA busy_timeout = {round(READ_TIMEOUT_S * 1000)}")
            # Before the quarantine: a run id is never given twice, even one whose row was set aside,
            # nor one given while the database could not be written (its row lost by a crash).
            self._run_ids = RunIdMark(self.path.with_name(self.path.name + ".run-ids"))
            self._max_seq = max(int(self._db.execute("SELECT COALESCE(MAX(seq), 0) FROM runs").fetchone()[0]),
                                self._run_ids.read())
        except sqlite3.DatabaseError as error:
            raise StoreError(f"{self.path}: cannot use the state database ({error})") from None
        except OSError as error:
            raise StoreError(f"{self.path}: cannot use the state database ({error.strerror})") from None
        try:
            self.quarantined += quarantine_bad_rows(self._db, t_ns=clock())
            if row_checks:
                self.quarantined += quarantine_unusable_rows(self._db, row_checks, t_ns=clock())
        except sqlite3.Error as error:
            log.warning("%s: bad rows not quarantined (%s); the loaders skip them", self.path, error)
        for line in self.quarantined:
            log.warning("state database: %s", line)
        self._lock = threading.Lock()
        self._runs: dict[str, _RunRow] = {}
        self._baselines: dict[str, tuple[int, str]] = {}
        self._calib: dict[int, _CalibOp] = {}
        self._calib_ids = itertools.count()
        self._alarms: dict[int, tuple[int, str | None, str, str]] = {}
        self._jobs: dict[str, JobRow] = {}
        self._read_health = "ok"
        self._count = int((self._query("SELECT COUNT(*) FROM runs WHERE json_valid(record)") or [(0,)])[0][0])
        self._sync_wait_s = sync_wait_s
        self._stalled_at = 0
        self._writer = BackgroundWriter(lambda: self._connect(2.0), self._apply, retry_min_s=retry_min_s,
                                        retry_max_s=retry_max_s)

    def _connect(self, timeout_s: float) -> sqlite3.Connection:
        db = sqlite3.connect(str(self.path), isolation_level=None, timeout=timeout_s, check_same_thread=False)
        if db.execute("PRAGMA journal_mode").fetchone()[0] != "wal":
            db.execute("PRAGMA journal_mode=WAL")
        db.execute("PRAGMA synchronous=FULL")
        return db

    def _schema_version(self) -> int | None:
        try:
            return schema_version(self._db)
        except ValueError as error:
            raise StoreError(f"{self.path}: {error}; refusing to guess what the file holds") from None

    @property
    def schema_version(self) -> int:
        """The schema version of the open file."""
        return int(self._schema_version() or SCHEMA_VERSION)

    def health(self) -> str:
        """``"ok"``, or ``"degraded: <reason>"`` while writes wait in memory or reads fail, or
        while the file system of the database is read-only (remounted so after an error): the next
        write would fail, and the replies would say ``"stored": false``."""
        writer = self._writer.health
        if writer != "ok":
            return f"{writer}; {self._writer.pending} writes pending"
        refusal = self._write_refusal()
        if refusal is not None:
            return f"degraded: state directory not writable ({refusal}); nothing can be stored"
        return self._read_health

    def _write_refusal(self) -> str | None:
        """Why the state directory's file system refuses writes now (two system calls, no disk I/O)."""
        try:
            if os.statvfs(self.path.parent).f_flag & os.ST_RDONLY:
                return "Read-only file system"
        except OSError:
            pass
        return self._run_ids.refusal()

    def flush(self, timeout_s: float = CLOSE_FLUSH_S) -> bool:
        """Wait until every saved record is written; False when ``timeout_s`` passed first."""
        return self._writer.flush(timeout_s)

    def close(self) -> None:
        """Write what is pending (up to :data:`CLOSE_FLUSH_S`), then close the database."""
        unsaved = self._writer.close(CLOSE_FLUSH_S)
        if unsaved:
            log.error("state database: %d writes could not be saved before exit (%s): %s", len(unsaved),
                      self._writer.health, ", ".join(str(op) for op in unsaved[:10]))
        self._run_ids.close()
        self._db.close()

    def _submit(self, op: Hashable) -> bool:
        """Queue a write; whether it is on disk on return (False: it waits in memory, retried)."""
        ticket = self._writer.submit(op)
        # Wait for the write while the database keeps up; after one wait timed out, not again
        # until that write went through (a lock or a slow disk costs the loop one wait, not one per save).
        waiting = self._sync_wait_s > 0 and self._writer.health == "ok" and self._writer.completed >= self._stalled_at
        if waiting and not self._writer.wait_for(ticket, self._sync_wait_s):
            self._stalled_at = ticket
        return self._writer.completed >= ticket

    # -- reading -------------------------------------------------------------------------------------

    def _query(self, sql: str, params: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
        """Rows of ``sql``; [] with a degraded health when the file cannot be read now."""
        try:
            rows = self._db.execute(sql, params).fetchall()
        except sqlite3.Error as error:
            reason = f"degraded: state database not readable ({error})"
            if reason != self._read_health:
                log.warning("%s; answering from memory", reason[len("degraded: "):])
            self._read_health = reason
            return []
        self._read_health = "ok"
        return rows

    # -- runs ----------------------------------------------------------------------------------------

    def next_run_id(self) -> str:
        """A run id not used before in this state directory: ``r<n>``."""
        return f"r{self._max_seq + 1}"

    def save_run(self, record: Mapping[str, Any]) -> bool:
        """Insert or replace a run record (``run_id`` of the form ``r<n>``); returns at once, True
        when the record is on disk then (False: it waits in memory, and its id is marked
        durably as given out: :class:`~hdeem_watch.daemon.store.run_ids.RunIdMark`)."""
        run_id = str(record["run_id"])
        row = _RunRow(seq=int(run_id.lstrip("r")), kernel=str(record.get("kernel", "")),
                      state=str(record.get("state", "")), t_start_ns=int(record.get("t_start_ns") or 0),
                      record=_dumps(record), summary=_dumps(run_summary(record)))
        with self._lock:
            self._runs[run_id] = row
            if row.seq > self._max_seq:
                self._max_seq = row.seq
                self._count += 1
        written = self._submit(("run", run_id))
        if not written and row.seq > self._run_ids.read():
            self._run_ids.write(row.seq)
        return written

    def get_run(self, run_id: str) -> dict[str, Any] | None:
        """One run record, or None."""
        with self._lock:
            row = self._runs.get(run_id)
            if row is not None:
                return _loads(row.record)
            rows = self._query("SELECT record FROM runs WHERE run_id = ? AND json_valid(record)", (run_id,))
        return _loads(rows[0][0]) if rows else None

    def list_runs(self, limit: int = 100, kernel: str | None = None, *, full: bool = False,
                  before: str | int | None = None) -> list[dict[str, Any]]:
        """Run records, newest first: summaries (:func:`~hdeem_watch.daemon.book.runs.run_summary`) unless ``full``.

        Args:
            limit: at most this many.
            kernel: only runs of this kernel.
            full: whole records (with the refit and the calibration row).
            before: only runs older than this run id (``"r17"`` or 17): the next page.
        """
        where: list[str] = ["json_valid(record)"]
        params: list[Any] = []
        if kernel is not None:
            where.append("kernel = ?")
            params.append(kernel)
        before_seq = None if before is None else int(str(before).lstrip("r"))
        if before_seq is not None:
            where.append("seq < ?")
            params.append(before_seq)
        column = "record" if full else _SUMMARY_SQL
        sql = f"SELECT seq, {column} FROM runs WHERE {' AND '.join(where)} ORDER BY seq DESC LIMIT ?"
        with self._lock:
            found: dict[int, Any] = {}
            for seq, text, *fit in self._query(sql, (*params, int(limit))):
                found[int(seq)] = _loads(text) if full else _summary_from_sql(text, *fit)
            for row in self._runs.values():
                if (kernel is None or row.kernel == kernel) and (before_seq is None or row.seq < before_seq):
                    found[row.seq] = _loads(row.record if full else row.summary)
        newest = sorted(found, reverse=True)[: max(0, int(limit))]
        return [r for r in (found[seq] for seq in newest) if isinstance(r, dict)]

    def close_interrupted_runs(self, t_ns: int) -> int:
        """Mark runs left ``running`` by a crashed daemon as ``aborted``; return how many."""
        with self._lock:
            texts = [r.record for r in self._runs.values() if r.state == "running"]
            texts += [t for (t,) in self._query("SELECT record FROM runs WHERE state = 'running' AND json_valid(record)")]
        closed = 0
        for record in (_loads(t) for t in texts):
            if not isinstance(record, dict) or "run_id" not in record:
                continue
            record["state"] = "aborted"
            record["model_error"] = "the daemon stopped during the run"
            record["t_stop_ns"] = record.get("t_stop_ns") or int(t_ns)
            self.save_run(record)
            closed += 1
        return closed

    def count_runs(self) -> int:
        """Number of stored runs (counting those still waiting to be written)."""
        return self._count

    # -- calibration ---------------------------------------------------------------------------------

    def save_calibration(self, t_ns: int, state: Mapping[str, Any] | str, fit: Mapping[str, Any] | None,
                         run_id: str | None) -> None:
        """Store the calibrator's state and append the fit to the history (one transaction, later).

        ``state`` may be JSON text already (the daemon serialises the large state on its worker).
        """
        self._save_calib(_CalibOp(int(t_ns), _dumps(state), None if fit is None else _dumps(fit), run_id))

    def save_calibrator_state(self, t_ns: int, state: Mapping[str, Any] | str) -> None:
        """Store the calibrator's state without a fit-history entry (e.g. after one group's reset)."""
        self._save_calib(_CalibOp(int(t_ns), _dumps(state), None, None))

    def clear_calibrator(self, t_ns: int) -> None:
        """Forget the calibrator state (``calib.reset``); the fit history keeps a null entry."""
        self._save_calib(_CalibOp(int(t_ns), None, None, None))

    def quarantine_calibrator(self, t_ns: int, reason: str) -> None:
        """Move the stored calibrator state, which could not be restored, to ``quarantine``."""
        self._save_calib(_CalibOp(int(t_ns), None, None, None, quarantine=" ".join(reason.split())[:200]))

    def _save_calib(self, op: _CalibOp) -> None:
        with self._lock:
            key = next(self._calib_ids)
            self._calib[key] = op
        self._submit(("calib", key))

    def load_calibrator(self) -> dict[str, Any] | None:
        """The last saved calibrator state, or None."""
        with self._lock:
            if self._calib:
                last = self._calib[max(self._calib)]
                return None if last.state is None else _loads(last.state)
            rows = self._query("SELECT state FROM calibrator WHERE id = 1 AND json_valid(state)")
        state = _loads(rows[0][0]) if rows else None
        return state if isinstance(state, dict) else None

    def fit_history(self, limit: int = 100) -> list[tuple[int, str | None, dict[str, Any] | None]]:
        """``(t_ns, run_id, fit or None)`` oldest first, the last ``limit`` entries."""
        with self._lock:
            rows = self._query("SELECT t_ns, run_id, fit FROM fits WHERE fit IS NULL OR json_valid(fit) "
                               "ORDER BY id DESC LIMIT ?", (int(limit),))
            pending = [(op.t_ns, op.run_id, op.fit) for _k, op in sorted(self._calib.items())
                       if op.quarantine is None and (op.state is None or op.fit is not None)]
        entries = [(int(t), r, f) for t, r, f in reversed(rows)] + pending
        return [(t, r, _loads(f)) for t, r, f in entries[-max(0, int(limit)):]] if limit > 0 else []

    # -- calibration alarms ---------------------------------------------------------------------------

    def save_alarm(self, t_ns: int, run_id: str | None, alarm: Mapping[str, Any]) -> None:
        """Append a drift alarm of a sensor group (``DriftAlarm.to_dict()``); returns at once."""
        with self._lock:
            key = next(self._calib_ids)
            self._alarms[key] = (int(t_ns), run_id, str(alarm.get("group")), _dumps(alarm))
        self._submit(("alarm", key))

    def list_alarms(self, limit: int = 100) -> list[dict[str, Any]]:
        """The last ``limit`` alarms, oldest first, each ``{"t_ns", "run_id", "alarm"}``."""
        with self._lock:
            rows = self._query("SELECT t_ns, run_id, alarm FROM alarms WHERE json_valid(alarm) ORDER BY id DESC LIMIT ?",
                               (int(limit),))
            pending = [(t, r, a) for _k, (t, r, _g, a) in sorted(self._alarms.items())]
        entries = [(int(t), r, a) for t, r, a in reversed(rows)] + pending
        return [{"t_ns": t, "run_id": r, "alarm": _loads(a)} for t, r, a in entries[-max(0, int(limit)):]] \
            if limit > 0 else []

    # -- baselines -----------------------------------------------------------------------------------

    def save_baseline(self, channel: str, record: Mapping[str, Any]) -> None:
        """Insert or replace a channel's baseline; returns at once."""
        with self._lock:
            self._baselines[channel] = (int(record.get("t_ns") or 0), _dumps(record))
        self._submit(("baseline", channel))

    def load_baselines(self) -> dict[str, dict[str, Any]]:
        """Every stored baseline by channel."""
        with self._lock:
            rows = self._query("SELECT channel, record FROM baselines WHERE json_valid(record)")
            texts = {c: r for c, r in rows} | {c: text for c, (_t, text) in self._baselines.items()}
        return {c: r for c, r in ((c, _loads(t)) for c, t in texts.items()) if isinstance(r, dict)}

    # -- SLURM jobs ----------------------------------------------------------------------------------

    def save_job(self, record: Mapping[str, Any]) -> bool:
        """Insert or replace a job record (keyed by job id and start time); returns at once, True
        when the record is on disk then."""
        key, row = job_row(record)
        with self._lock:
            self._jobs[key] = row
        return self._submit(("job", key))

    def list_jobs(self, *, job_id: str | None = None, user: str | None = None, since_ns: int | None = None,
                  state: str | None = None, limit: int = 100) -> list[dict[str, Any]]:
        """Job records, newest start first: only ``job_id``'s, ``user``'s, those running at or
        after ``since_ns`` (started then, or not yet stopped), or in ``state``; at most ``limit``."""
        sql, params = job_query(job_id=job_id, user=user, since_ns=since_ns, state=state, limit=limit)
        with self._lock:
            found = {key: text for key, text in self._query(sql, tuple(params))}
            found |= {key: row.record for key, row in self._jobs.items()}
        records = [r for r in (_loads(t) for t in found.values()) if isinstance(r, dict)]
        chosen = [r for r in records if job_matches(r, job_id=job_id, user=user, since_ns=since_ns, state=state)]
        chosen.sort(key=lambda r: int(r.get("t_start_ns") or 0), reverse=True)
        return chosen[: max(0, int(limit))]

    # -- the writer's side ---------------------------------------------------------------------------

    def _apply(self, db: sqlite3.Connection, op: Hashable) -> None:
        """Write one operation (on the writer thread); the overlay entry goes once it is committed."""
        assert isinstance(op, tuple)
        kind, key = op
        tables: dict[str, dict[Any, Any]] = {"run": self._runs, "baseline": self._baselines, "calib": self._calib,
                                             "alarm": self._alarms, "job": self._jobs}
        with self._lock:
            pending: Any = tables[kind].get(key)
        if pending is None:
            return  # written already by an earlier operation on the same key
        db.execute("BEGIN IMMEDIATE")
        if kind == "run":
            db.execute(INSERT_RUN, (key, pending.seq, pending.kernel, pending.state, pending.t_start_ns, pending.record))
        elif kind == "baseline":
            db.execute("INSERT OR REPLACE INTO baselines (channel, t_ns, record) VALUES (?, ?, ?)", (key, *pending))
        elif kind == "job":
            db.execute(INSERT_JOB, pending.values(key))
        elif kind == "alarm":
            db.execute("INSERT INTO alarms (t_ns, run_id, grp, alarm) VALUES (?, ?, ?, ?)", pending)
        elif pending.quarantine is not None:
            db.execute("INSERT INTO quarantine (t_ns, source, row_key, content, reason) SELECT ?, 'calibrator', "
                       "id, state, ? FROM calibrator", (pending.t_ns, f"unusable: {pending.quarantine}"))
            db.execute("DELETE FROM calibrator")
        elif pending.state is None:
            db.execute("DELETE FROM calibrator")
            db.execute("INSERT INTO fits (t_ns, run_id, fit) VALUES (?, NULL, NULL)", (pending.t_ns,))
        else:
            db.execute("INSERT OR REPLACE INTO calibrator (id, t_ns, state) VALUES (1, ?, ?)",
                       (pending.t_ns, pending.state))
            if pending.fit is not None:
                db.execute("INSERT INTO fits (t_ns, run_id, fit) VALUES (?, ?, ?)",
                           (pending.t_ns, pending.run_id, pending.fit))
        # Commit and drop the overlay entry atomically for the readers (they hold the same lock).
        with self._lock:
            db.execute("COMMIT")
            if tables[kind].get(key) is pending:
                del tables[kind][key]
