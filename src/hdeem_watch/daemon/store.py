"""The daemon's persistent state: runs, calibration fits and calibrator state, baselines.

One SQLite file (``state.db``) in the state directory, in WAL mode with ``synchronous=FULL``:
every write is one committed transaction, so a ``kill -9`` at any moment loses nothing that was
acknowledged, and a restarted daemon continues where the previous one stopped. The schema is
versioned (table ``meta``, key ``schema_version``); a newer schema than this code knows is refused
rather than misread.

Records are stored as JSON text (NaN as null) beside the columns used for lookups.

Example:
    >>> import tempfile, pathlib
    >>> store = Store(pathlib.Path(tempfile.mkdtemp()) / "state.db")
    >>> run_id = store.next_run_id()
    >>> store.save_run({"run_id": run_id, "kernel": "triad", "state": "running", "t_start_ns": 1})
    >>> [r["kernel"] for r in store.list_runs()]
    ['triad']
    >>> store.close()
"""

from __future__ import annotations

import contextlib
import json
import sqlite3
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from hdeem_watch.daemon.protocol import jsonable

#: The schema this code writes.
SCHEMA_VERSION = 1

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS runs (
    run_id TEXT PRIMARY KEY,
    seq INTEGER NOT NULL UNIQUE,
    kernel TEXT NOT NULL,
    state TEXT NOT NULL,
    t_start_ns INTEGER NOT NULL,
    record TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS fits (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    t_ns INTEGER NOT NULL,
    run_id TEXT,
    fit TEXT
);
CREATE TABLE IF NOT EXISTS calibrator (id INTEGER PRIMARY KEY CHECK (id = 1), t_ns INTEGER NOT NULL, state TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS baselines (channel TEXT PRIMARY KEY, t_ns INTEGER NOT NULL, record TEXT NOT NULL);
"""


class StoreError(RuntimeError):
    """The state database cannot be used (newer schema, corrupt file)."""


def _dumps(value: Any) -> str:
    """Strict JSON text (NaN as null); a ``str`` is taken as JSON text already (serialised elsewhere)."""
    if isinstance(value, str):
        return value
    return json.dumps(jsonable(value), separators=(",", ":"), allow_nan=False)


class Store:
    """SQLite state of one daemon (single-threaded use; open one per process).

    Args:
        path: the database file; its directory is created (mode 0750) if missing.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True, mode=0o750)
        try:
            self._db = sqlite3.connect(str(self.path), isolation_level=None, timeout=5.0, check_same_thread=False)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=FULL")
            version = self._schema_version()
            if version is not None and version > SCHEMA_VERSION:
                raise StoreError(f"{self.path}: schema version {version} is newer than this daemon's {SCHEMA_VERSION}")
            with self._transaction():
                for statement in _SCHEMA.strip().split(";"):
                    if statement.strip():
                        self._db.execute(statement)
                self._db.execute(
                    "INSERT OR IGNORE INTO meta (key, value) VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),)
                )
        except sqlite3.DatabaseError as error:
            raise StoreError(f"{self.path}: cannot use the state database ({error})") from None

    @contextlib.contextmanager
    def _transaction(self) -> Iterator[None]:
        """One explicit transaction: committed on success, rolled back on an exception."""
        self._db.execute("BEGIN IMMEDIATE")
        try:
            yield
        except BaseException:
            self._db.execute("ROLLBACK")
            raise
        self._db.execute("COMMIT")

    def _schema_version(self) -> int | None:
        exists = self._db.execute("SELECT name FROM sqlite_master WHERE type='table' AND name='meta'").fetchone()
        if not exists:
            return None
        row = self._db.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()
        return int(row[0]) if row else None

    @property
    def schema_version(self) -> int:
        """The schema version of the open file."""
        return int(self._schema_version() or SCHEMA_VERSION)

    def close(self) -> None:
        """Close the database (a WAL checkpoint happens on the last close)."""
        self._db.close()

    # -- runs ----------------------------------------------------------------------------------

    def next_run_id(self) -> str:
        """A run id not used before in this state directory: ``r<n>``."""
        row = self._db.execute("SELECT COALESCE(MAX(seq), 0) FROM runs").fetchone()
        return f"r{int(row[0]) + 1}"

    def save_run(self, record: Mapping[str, Any]) -> None:
        """Insert or replace a run record (``run_id`` of the form ``r<n>``)."""
        run_id = str(record["run_id"])
        seq = int(run_id.lstrip("r"))
        with self._transaction():
            self._db.execute(
                "INSERT OR REPLACE INTO runs (run_id, seq, kernel, state, t_start_ns, record) VALUES (?,?,?,?,?,?)",
                (run_id, seq, str(record.get("kernel", "")), str(record.get("state", "")),
                 int(record.get("t_start_ns") or 0), _dumps(record)),
            )

    def get_run(self, run_id: str) -> dict[str, Any] | None:
        """One run record, or None."""
        row = self._db.execute("SELECT record FROM runs WHERE run_id = ?", (run_id,)).fetchone()
        return json.loads(row[0]) if row else None

    def list_runs(self, limit: int = 100, kernel: str | None = None) -> list[dict[str, Any]]:
        """Run records, newest first."""
        if kernel is None:
            rows = self._db.execute("SELECT record FROM runs ORDER BY seq DESC LIMIT ?", (limit,)).fetchall()
        else:
            rows = self._db.execute(
                "SELECT record FROM runs WHERE kernel = ? ORDER BY seq DESC LIMIT ?", (kernel, limit)
            ).fetchall()
        return [json.loads(r[0]) for r in rows]

    def close_interrupted_runs(self, t_ns: int) -> int:
        """Mark runs left ``running`` by a crashed daemon as ``aborted``; return how many."""
        rows = self._db.execute("SELECT record FROM runs WHERE state = 'running'").fetchall()
        for (text,) in rows:
            record = json.loads(text)
            record["state"] = "aborted"
            record["model_error"] = "the daemon stopped during the run"
            record["t_stop_ns"] = record.get("t_stop_ns") or int(t_ns)
            self.save_run(record)
        return len(rows)

    def count_runs(self) -> int:
        """Number of stored runs."""
        return int(self._db.execute("SELECT COUNT(*) FROM runs").fetchone()[0])

    # -- calibration ---------------------------------------------------------------------------

    def save_calibration(self, t_ns: int, state: Mapping[str, Any] | str, fit: Mapping[str, Any] | None,
                         run_id: str | None) -> None:
        """Store the calibrator's state and append the fit to the history, in one transaction.

        ``state`` may be JSON text already (the daemon serialises the large state on its worker).
        """
        with self._transaction():
            self._db.execute(
                "INSERT OR REPLACE INTO calibrator (id, t_ns, state) VALUES (1, ?, ?)", (int(t_ns), _dumps(state))
            )
            self._db.execute(
                "INSERT INTO fits (t_ns, run_id, fit) VALUES (?, ?, ?)",
                (int(t_ns), run_id, None if fit is None else _dumps(fit)),
            )

    def load_calibrator(self) -> dict[str, Any] | None:
        """The last saved calibrator state, or None."""
        row = self._db.execute("SELECT state FROM calibrator WHERE id = 1").fetchone()
        return json.loads(row[0]) if row else None

    def clear_calibrator(self, t_ns: int) -> None:
        """Forget the calibrator state (``calib.reset``); the fit history keeps a null entry."""
        with self._transaction():
            self._db.execute("DELETE FROM calibrator")
            self._db.execute("INSERT INTO fits (t_ns, run_id, fit) VALUES (?, NULL, NULL)", (int(t_ns),))

    def fit_history(self, limit: int = 100) -> list[tuple[int, str | None, dict[str, Any] | None]]:
        """``(t_ns, run_id, fit or None)`` oldest first, the last ``limit`` entries."""
        rows = self._db.execute("SELECT t_ns, run_id, fit FROM fits ORDER BY id DESC LIMIT ?", (limit,)).fetchall()
        return [(int(t), r, None if f is None else json.loads(f)) for t, r, f in reversed(rows)]

    # -- baselines -----------------------------------------------------------------------------

    def save_baseline(self, channel: str, record: Mapping[str, Any]) -> None:
        """Insert or replace a channel's baseline."""
        with self._transaction():
            self._db.execute(
                "INSERT OR REPLACE INTO baselines (channel, t_ns, record) VALUES (?, ?, ?)",
                (channel, int(record.get("t_ns") or 0), _dumps(record)),
            )

    def load_baselines(self) -> dict[str, dict[str, Any]]:
        """Every stored baseline by channel."""
        rows = self._db.execute("SELECT channel, record FROM baselines").fetchall()
        return {c: json.loads(r) for c, r in rows}
