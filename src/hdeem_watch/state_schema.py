"""The schema of the state database (``state.db``): its one owner.

Every module that touches the file's tables takes their names and columns from here: the store
(:mod:`~hdeem_watch.daemon.store.database`, which creates the tables and writes them), the SLURM jobs table
(:mod:`~hdeem_watch.daemon.store.jobs`), the start-up repair (:mod:`~hdeem_watch.daemon.store.repair`)
and the report's reader (:mod:`hdeem_watch.report.state_reader`; ``report`` sits above ``daemon`` in
the layering, so it may import this module, which imports nothing of the daemon).

The schema is versioned (table ``meta``, key ``schema_version``): :data:`SCHEMA_VERSION` is the
version this code writes; a reader of an older or newer file asks :func:`table_columns` what is there.

Example:
    >>> import sqlite3
    >>> db = sqlite3.connect(":memory:")
    >>> _ = db.executescript(SCHEMA)
    >>> set(TABLES) <= set(table_columns(db)), table_columns(db)["baselines"]
    (True, ['channel', 't_ns', 'record'])
    >>> schema_version(db) is None  # the store writes it when it creates the file
    True
"""

from __future__ import annotations

import sqlite3
from typing import NamedTuple

#: The schema this code writes.
SCHEMA_VERSION = 1

#: The tables and indexes of :data:`SCHEMA_VERSION` (idempotent: ``IF NOT EXISTS``).
SCHEMA = """
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
CREATE TABLE IF NOT EXISTS alarms (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    t_ns INTEGER NOT NULL,
    run_id TEXT,
    grp TEXT NOT NULL,
    alarm TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS jobs (
    job_key TEXT PRIMARY KEY,
    job_id TEXT NOT NULL,
    user TEXT NOT NULL,
    state TEXT NOT NULL,
    t_start_ns INTEGER NOT NULL,
    record TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS jobs_by_start ON jobs (t_start_ns);
CREATE INDEX IF NOT EXISTS jobs_by_id ON jobs (job_id);
CREATE TABLE IF NOT EXISTS quarantine (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    t_ns INTEGER NOT NULL,
    source TEXT NOT NULL,
    row_key TEXT,
    content TEXT,
    reason TEXT NOT NULL
);
"""


class Table(NamedTuple):
    """One table of :data:`SCHEMA`: its key column, its JSON column (None: no JSON) and all columns."""

    key: str
    json: str | None
    columns: tuple[str, ...]


#: Per table of :data:`SCHEMA`: key, JSON column, columns (in the order of :data:`SCHEMA`).
TABLES = {
    "meta": Table("key", None, ("key", "value")),
    "runs": Table("run_id", "record", ("run_id", "seq", "kernel", "state", "t_start_ns", "record")),
    "fits": Table("id", "fit", ("id", "t_ns", "run_id", "fit")),
    "calibrator": Table("id", "state", ("id", "t_ns", "state")),
    "baselines": Table("channel", "record", ("channel", "t_ns", "record")),
    "alarms": Table("id", "alarm", ("id", "t_ns", "run_id", "grp", "alarm")),
    "jobs": Table("job_key", "record", ("job_key", "job_id", "user", "state", "t_start_ns", "record")),
    "quarantine": Table("id", None, ("id", "t_ns", "source", "row_key", "content", "reason")),
}

#: The tables every reader of a hdeem-watch state needs (a file without them is not one).
REQUIRED_TABLES = ("runs",)

#: Insert or replace one run row.
INSERT_RUN = "INSERT OR REPLACE INTO runs (run_id, seq, kernel, state, t_start_ns, record) VALUES (?,?,?,?,?,?)"
#: Insert or replace one job row (``job_key`` = ``<job id>@<start ns>``: a requeued job starts anew).
INSERT_JOB = ("INSERT OR REPLACE INTO jobs (job_key, job_id, user, state, t_start_ns, record) "
              "VALUES (?,?,?,?,?,?)")


def table_columns(db: sqlite3.Connection) -> dict[str, list[str]]:
    """The tables of the open file and their columns (whatever version wrote it)."""
    names = [r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")]
    return {name: [c[1] for c in db.execute(f'PRAGMA table_info("{name}")')] for name in names}


def has_every_table(db: sqlite3.Connection) -> bool:
    """Whether the open file holds every table of :data:`SCHEMA`."""
    names = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    return set(TABLES) <= names


def schema_version(db: sqlite3.Connection) -> int | None:
    """The file's ``meta.schema_version``; None when it has none (a new file).

    Raises:
        ValueError: the version is not a number (the file is not to be guessed at).
    """
    exists = db.execute("SELECT name FROM sqlite_master WHERE type='table' AND name='meta'").fetchone()
    if not exists:
        return None
    row = db.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()
    if row is None:
        return None
    try:
        return int(row[0])
    except (TypeError, ValueError):
        raise ValueError(f"meta.schema_version = {row[0]!r} is not a version number") from None
