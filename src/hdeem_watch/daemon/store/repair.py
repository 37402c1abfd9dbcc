"""Start-up checks of the state database: damaged pages salvaged, bad rows quarantined.

A daemon must come up after a crash, a bad disk or a hand-edited file, without losing what can
still be read and without guessing at what cannot:

* :func:`salvage_if_corrupt`: when SQLite's ``quick_check`` finds damaged pages, every row that can
  still be read is copied into a fresh file, which takes the database's place; the damaged file is
  kept beside it as ``state.db.corrupt-<ns>`` for a post-mortem. A file cut short (truncated) is
  read up to where it ends. (The ``sqlite3`` shell's ``.recover`` needs its ``sqlite_dbpage``
  table, which Debian 12's shell is built without; the row scan here needs nothing but SQLite.)
* :func:`quarantine_bad_rows`: rows whose JSON is malformed or not an object move to the
  ``quarantine`` table (table, key, text, reason), out of the way of the loaders;
  :func:`quarantine_unusable_rows` likewise the rows of valid JSON the daemon cannot use
  (:mod:`~hdeem_watch.daemon.store.checks`).

Both return one line per finding for the log and the ``quarantined`` list.

Example:
    >>> import sqlite3
    >>> db = sqlite3.connect(":memory:", isolation_level=None)
    >>> _ = db.executescript(SCHEMA)
    >>> _ = db.execute("INSERT INTO baselines VALUES ('DDR_AB', 1, '{oops')")
    >>> quarantine_bad_rows(db, t_ns=5)
    ["baselines 'DDR_AB': malformed JSON (moved to table quarantine)"]
"""

from __future__ import annotations

import json
import logging
import os
import sqlite3
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from hdeem_watch.state_schema import SCHEMA, TABLES

log = logging.getLogger("hdeem_watch.daemon.store.database")

#: Most point look-ups a salvage spends on the rows between two damaged regions of one table.
MAX_PROBES = 200_000


def quarantine_bad_rows(db: sqlite3.Connection, *, t_ns: int) -> list[str]:
    """Move rows whose JSON column is malformed or not an object to ``quarantine``; one line each.

    Runs in one transaction on an autocommit connection; raises ``sqlite3.Error`` when it cannot
    write (the readers skip such rows anyway).
    """
    found: list[tuple[str, object, str, str]] = []
    for table, (key, column, _columns) in TABLES.items():
        if column is None:
            continue
        query = (f"SELECT rowid, {key}, json_valid({column}) FROM {table} "
                 f"WHERE {column} IS NOT NULL AND CASE WHEN json_valid({column}) THEN json_type({column}) != 'object' "
                 "ELSE 1 END")
        for rowid, row_key, valid in db.execute(query).fetchall():
            found.append((table, rowid, str(row_key), "not a JSON object" if valid else "malformed JSON"))
    return _move_to_quarantine(db, found, t_ns)


def quarantine_unusable_rows(db: sqlite3.Connection, checks: Mapping[str, Any], *, t_ns: int) -> list[str]:
    """Move rows of valid JSON that the daemon cannot use to ``quarantine``; one line each.

    ``checks``: per table a :class:`~hdeem_watch.daemon.store.checks.RowCheck` (``check``,
    ``where``, ``newest``); a row whose check raises is moved, the reason naming the error.
    """
    found: list[tuple[str, object, str, str]] = []
    for table, rule in checks.items():
        key, column, _columns = TABLES[table]
        query = (f"SELECT rowid, {key}, {column} FROM {table} WHERE {column} IS NOT NULL AND json_valid({column}) "
                 f"AND ({rule.where}) ORDER BY rowid DESC")
        if rule.newest is not None:
            query += f" LIMIT {int(rule.newest)}"
        for rowid, row_key, text in db.execute(query).fetchall():
            try:
                rule.check(json.loads(text))
            except Exception as error:  # whatever the reader would have met
                reason = " ".join(f"unusable: {type(error).__name__}: {error}".split())
                found.append((table, rowid, str(row_key), reason[:200]))
    return _move_to_quarantine(db, found, t_ns)


def _move_to_quarantine(db: sqlite3.Connection, found: list[tuple[str, object, str, str]], t_ns: int) -> list[str]:
    """Move ``(table, rowid, key, reason)`` rows to ``quarantine`` in one transaction; one line each."""
    if not found:
        return []
    db.execute("BEGIN IMMEDIATE")
    try:
        for table, rowid, row_key, reason in found:
            column = TABLES[table][1]
            db.execute(f"INSERT INTO quarantine (t_ns, source, row_key, content, reason) "
                       f"SELECT ?, ?, ?, {column}, ? FROM {table} WHERE rowid = ?", (t_ns, table, row_key, reason, rowid))
            db.execute(f"DELETE FROM {table} WHERE rowid = ?", (rowid,))
    except BaseException:
        db.execute("ROLLBACK")
        raise
    db.execute("COMMIT")
    return [f"{table} {row_key!r}: {reason} (moved to table quarantine)" for table, _r, row_key, reason in found]


#: The most a state database file may allow (SQLite gives its ``-wal`` and ``-shm`` the same mode).
STATE_FILE_MODE = 0o640


def create_private(path: Path) -> None:
    """Create ``path`` empty with mode 0600 when it is missing, whatever the umask (SQLite would
    create it 0644 less the umask); an existing file is narrowed to :data:`STATE_FILE_MODE`.

    Raises:
        OSError: it cannot be created.
    """
    try:
        os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o600))
        return
    except FileExistsError:
        pass
    mode = os.stat(path).st_mode & 0o7777
    if mode & ~STATE_FILE_MODE:
        try:
            os.chmod(path, mode & STATE_FILE_MODE)
        except OSError as error:  # a read-only file system: the daemon still reads it
            log.warning("%s: mode %04o not narrowed to %04o (%s)", path, mode, mode & STATE_FILE_MODE, error.strerror)


def is_corrupt(db: sqlite3.Connection) -> str | None:
    """SQLite's ``quick_check`` verdict: None when the file is sound, else its first complaint."""
    try:
        rows = db.execute("PRAGMA quick_check(5)").fetchall()
    except sqlite3.DatabaseError as error:
        return str(error)
    verdict = [str(r[0]) for r in rows]
    return None if verdict == ["ok"] else "; ".join(verdict)


def salvage_if_corrupt(path: Path, *, t_ns: int) -> list[str]:
    """Replace a damaged database by a fresh one holding every readable row; one line per loss.

    Returns [] when the file is sound (or absent).

    Raises:
        sqlite3.DatabaseError: the file is not an SQLite database at all (nothing to salvage).
        OSError: the fresh file cannot be written.
    """
    if not path.exists():
        return []
    # Read-write (a read-only open cannot recover a WAL left without its -shm), but only reading.
    source = sqlite3.connect(str(path), isolation_level=None, timeout=0.5)
    source.execute("PRAGMA query_only = 1")
    # A file shorter than its header says (truncated: a full disk during a copy, a crash of the file
    # system) is refused as a whole unless the schema is "writable": SQLite then reads the pages
    # that are there (query_only: nothing is written all the same).
    source.execute("PRAGMA writable_schema = 1")
    try:
        problem = is_corrupt(source)
        if problem is None:
            return []
        if "not a database" in problem:
            raise sqlite3.DatabaseError(problem)
        log.error("%s is damaged (%s); salvaging the readable rows", path, problem)
        fresh_path = path.with_name(path.name + ".salvage")
        fresh_path.unlink(missing_ok=True)
        create_private(fresh_path)
        fresh = sqlite3.connect(str(fresh_path), isolation_level=None)
        lost: list[str] = [f"{path.name}: damaged ({' '.join(problem.split())[:200]}); kept as "
                           f"{path.name}.corrupt-{t_ns}"]
        try:
            fresh.executescript(SCHEMA)
            fresh.execute("BEGIN")
            for table, (_key, _column, columns) in TABLES.items():
                try:
                    if not source.execute("SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = ?",
                                          (table,)).fetchone():
                        continue  # a table newer than the file (e.g. alarms)
                    rows, unreadable = _readable_rows(source, table, columns)
                except sqlite3.DatabaseError as error:
                    lost.append(f"{table}: unreadable ({error})")
                    continue
                marks = ",".join("?" * len(columns))
                fresh.executemany(f"INSERT OR IGNORE INTO {table} ({','.join(columns)}) VALUES ({marks})", rows)
                if unreadable:
                    lost.append(f"{table}: rows in damaged or missing pages lost (at least {unreadable}), "
                                f"{len(rows)} kept")
            fresh.execute("COMMIT")
        finally:
            fresh.close()
    finally:
        source.close()
    for suffix in ("", "-wal", "-shm"):
        old = Path(str(path) + suffix)
        if old.exists():
            os.replace(old, Path(f"{path}.corrupt-{t_ns}{suffix}"))
    os.replace(fresh_path, path)
    return lost


def _readable_rows(db: sqlite3.Connection, table: str, columns: tuple[str, ...]) -> tuple[list[tuple[Any, ...]], int]:
    """Every row of ``table`` that can be read, and how many rowids in its range could not.

    Scans forward by rowid until a damaged page stops it, backward likewise, then probes the rowids
    in between one by one (at most :data:`MAX_PROBES`).
    """
    select = f"SELECT rowid, {','.join(columns)} FROM {table}"
    rows: dict[int, tuple[Any, ...]] = {}
    stopped = False
    for order in ("ASC", "DESC"):
        try:
            for row in _scan(db, f"{select} ORDER BY rowid {order}"):
                rows[int(row[0])] = tuple(row[1:])
        except sqlite3.DatabaseError:
            stopped = True
    if not stopped:
        return list(rows.values()), 0
    try:
        high = max([*rows, int(db.execute(f"SELECT COALESCE(MAX(rowid), 0) FROM {table}").fetchone()[0])])
    except sqlite3.DatabaseError:
        high = max(rows, default=0)
    unreadable = 0
    missing = [i for i in range(1, high) if i not in rows]
    for probes, rowid in enumerate(missing):
        if probes >= MAX_PROBES:
            unreadable += len(missing) - probes
            break
        try:
            row = db.execute(f"{select} WHERE rowid = ?", (rowid,)).fetchone()
        except sqlite3.DatabaseError:
            unreadable += 1
            continue
        if row is not None:
            rows[rowid] = tuple(row[1:])
    return [rows[i] for i in sorted(rows)], max(unreadable, 1)


def _scan(db: sqlite3.Connection, query: str) -> Iterator[tuple[Any, ...]]:
    cursor = db.execute(query)
    while (row := cursor.fetchone()) is not None:
        yield row
