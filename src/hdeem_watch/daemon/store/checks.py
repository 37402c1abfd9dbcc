"""What a stored row must be for the daemon to use it: the start-up checks of the state database.

:mod:`~hdeem_watch.daemon.store.repair` sets aside rows whose JSON is malformed; a row can also be
valid JSON of the wrong shape (a hand edit, a bug of an older version, a bit flip inside a string):
``{"currents": [1, 2]}`` as a fit once stopped the daemon at every start. Each check below reads a
row the way the daemon's start-up reads it (the same functions) and raises when it cannot; the row
then goes to the ``quarantine`` table and the daemon starts with the rest
(:func:`~hdeem_watch.daemon.store.repair.quarantine_unusable_rows`).

Only the rows the daemon loads at start are read (runs and jobs a crash left open, the newest fits,
every baseline and alarm); the calibrator's state is checked by restoring it
(:meth:`~hdeem_watch.daemon.store.database.Store.quarantine_calibrator` when that fails).

Example:
    >>> check = ROW_CHECKS["fits"].check
    >>> check({"n_runs": 3, "error": {"after": 0.1}, "currents": {"idd0": {"calibrated": 0.05}}})
    >>> check({"n_runs": 3, "error": {}, "currents": [1, 2]})
    Traceback (most recent call last):
    ...
    ValueError: fit: currents = '[1, 2]': expected an object
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from hdeem_watch.calibrate.run_model import MAX_HISTORY
from hdeem_watch.daemon.book.baselines import Baseline
from hdeem_watch.daemon.book.runs import run_summary
from hdeem_watch.daemon.jobs.records import job_summary
from hdeem_watch.daemon.store.jobs import job_row
from hdeem_watch.fit_record import FitRecord
from hdeem_watch.job_record import JobRecord
from hdeem_watch.run_record import RunRecord

_RUN_ID = re.compile(r"^r\d{1,18}$")


@dataclass(frozen=True)
class RowCheck:
    """The check of one table's rows.

    Attributes:
        check: raises when the row's JSON value cannot be used.
        where: SQL condition of the rows checked (those the daemon loads at start).
        newest: check only the newest rows (by rowid), None for all that match.
    """

    check: Callable[[Mapping[str, Any]], object]
    where: str = "1"
    newest: int | None = None


def check_open_run(record: Mapping[str, Any]) -> None:
    """A run a crash left ``running`` (closed as aborted at start) or ``modelling`` (modelled again)."""
    run_id = record.get("run_id")
    if not isinstance(run_id, str) or not _RUN_ID.match(run_id):
        raise ValueError(f"run_id {str(run_id)[:40]!r}: expected r<n>")
    int(record.get("t_start_ns") or 0)
    str(record.get("kernel", ""))
    run_summary(record)
    if record.get("state") == "modelling":
        RunRecord.from_dict(record, strict=True)


def check_open_job(record: Mapping[str, Any]) -> None:
    """A job a previous daemon left running (resumed at start, listed in every ``status``)."""
    JobRecord.from_dict(record, strict=True)
    job_row(record)
    job_summary(record)


def check_fit(fit: Mapping[str, Any]) -> None:
    """A fit of the history (the ``calib`` body's ``history`` entries): every field readable."""
    FitRecord.from_dict(fit, strict=True)


def check_alarm(alarm: Mapping[str, Any]) -> None:
    """A drift alarm (``DriftAlarm.to_dict()``): its group names the row."""
    if not isinstance(alarm.get("group"), str):
        raise ValueError(f"alarm group {str(alarm.get('group'))[:40]!r}: expected a sensor group name")


#: Per table: how its rows are checked at start.
ROW_CHECKS: dict[str, RowCheck] = {
    "runs": RowCheck(check_open_run, where="state IN ('running', 'modelling')"),
    "jobs": RowCheck(check_open_job, where="state = 'running'"),
    "fits": RowCheck(check_fit, newest=5 * MAX_HISTORY),
    "baselines": RowCheck(Baseline.from_dict),
    "alarms": RowCheck(check_alarm, newest=5 * MAX_HISTORY),
}
