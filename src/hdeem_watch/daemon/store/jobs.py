"""The ``jobs`` table of the state database: rows, the filters of ``job.list``, in SQL and in memory.

:class:`~hdeem_watch.daemon.store.database.Store` keeps job records like runs (written by its writer thread,
visible to reads while they wait in memory); this module holds what is particular to jobs: the row
of a record (the table and its insert are :mod:`~hdeem_watch.state_schema`'s), the query of
:meth:`Store.list_jobs` and the same filters on the records still in memory.

Example:
    >>> key, row = job_row({"job_id": "42", "user": "alice", "state": "done", "t_start_ns": 5})
    >>> key, row.user
    ('42@5', 'alice')
    >>> job_query(user="alice", limit=10)[1]
    ['alice', 10]
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from hdeem_watch.wire.protocol import jsonable


@dataclass(frozen=True)
class JobRow:
    """One row of the ``jobs`` table (the record as JSON text)."""

    job_id: str
    user: str
    state: str
    t_start_ns: int
    record: str

    def values(self, key: str) -> tuple[Any, ...]:
        """The parameters of :data:`INSERT_JOB`."""
        return (key, self.job_id, self.user, self.state, self.t_start_ns, self.record)


def job_row(record: Mapping[str, Any]) -> tuple[str, JobRow]:
    """``(key, row)`` of a job record (serialised now, on the caller's thread)."""
    row = JobRow(job_id=str(record["job_id"]), user=str(record.get("user") or ""), state=str(record.get("state", "")),
                 t_start_ns=int(record.get("t_start_ns") or 0),
                 record=json.dumps(jsonable(record), separators=(",", ":"), allow_nan=False))
    return f"{row.job_id}@{row.t_start_ns}", row


def job_query(*, job_id: str | None = None, user: str | None = None, since_ns: int | None = None,
              state: str | None = None, limit: int = 100) -> tuple[str, list[Any]]:
    """The SQL and parameters of ``job.list``'s filters, newest start first."""
    where: list[str] = ["json_valid(record)"]
    params: list[Any] = []
    for column, value in (("job_id", job_id), ("user", user), ("state", state)):
        if value is not None:
            where.append(f"{column} = ?")
            params.append(value)
    if since_ns is not None:
        where.append("(t_start_ns >= ? OR state = 'running' OR COALESCE(json_extract(record, '$.t_stop_ns'), 0) >= ?)")
        params += [since_ns, since_ns]
    sql = f"SELECT job_key, record FROM jobs WHERE {' AND '.join(where)} ORDER BY t_start_ns DESC LIMIT ?"
    return sql, [*params, int(limit)]


def job_matches(record: Mapping[str, Any], *, job_id: str | None = None, user: str | None = None,
                since_ns: int | None = None, state: str | None = None) -> bool:
    """The filters of :func:`job_query` on a record (for those still waiting in memory)."""
    if (job_id is not None and record.get("job_id") != job_id) or (user is not None and record.get("user") != user):
        return False
    if state is not None and record.get("state") != state:
        return False
    if since_ns is None or record.get("state") == "running":
        return True
    return max(int(record.get("t_start_ns") or 0), int(record.get("t_stop_ns") or 0)) >= since_ns
