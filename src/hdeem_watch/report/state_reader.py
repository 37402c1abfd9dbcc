"""Read a daemon's state directory (``state.db``) into :class:`~hdeem_watch.report.records.ReportData`.

The database is opened read-only (``mode=ro``), so a report can be drawn while the daemon runs and
never changes the state. Which tables a state has, and their columns, is asked of the schema's owner
(:mod:`hdeem_watch.state_schema`; ``report`` sits above ``daemon`` in the layering). Only the
tables and columns of schema version 1 are required (``runs``, ``fits``, ``calibrator``,
``baselines``); tables a newer daemon adds are ignored unless they are
known here (a ``jobs`` table of JSON job records; a ``group`` column of ``fits`` for per-pair fits;
further ``baseline*`` tables with ``channel``/``t_ns``/``record`` columns as baseline history).

Example::

    data = read_state("/var/lib/hdeem-watch")
    [run.label for run in data.runs]     # ['idle', 'triad 24t', ...]
"""

from __future__ import annotations

import json
import math
import sqlite3
import urllib.parse
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from hdeem_watch.errors import InputError
from hdeem_watch.fit_record import FitRecord
from hdeem_watch.job_record import JobRecord
from hdeem_watch.report.analysis import jobs_from_runs, model_currents
from hdeem_watch.report.records import (
    BaselinePoint,
    FitEntry,
    JobRow,
    ReportData,
    RunRow,
    finite,
    is_dram_channel,
)
from hdeem_watch.run_record import RunRecord
from hdeem_watch.state_schema import REQUIRED_TABLES, table_columns

#: Column names under which a newer schema may keep the sensor group of a fit.
_GROUP_COLUMNS = ("group", "grp", "sensor_group")


def state_path(path: str | Path) -> Path:
    """The ``state.db`` of a state directory (or the file itself when given one).

    Raises:
        InputError: no such directory or file.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "state.db"
    if not path.is_file():
        raise InputError(f"{path}: no daemon state there (expected a state directory with state.db)")
    return path


def _connect(path: Path) -> sqlite3.Connection:
    uri = f"file:{urllib.parse.quote(str(path.resolve()))}?mode=ro"
    try:
        db = sqlite3.connect(uri, uri=True, timeout=5.0)
        db.execute("SELECT count(*) FROM sqlite_master").fetchone()
    except sqlite3.DatabaseError as error:
        raise InputError(f"{path}: cannot read the state database ({error})") from None
    return db


def _json(text: Any) -> Any:
    if text is None:
        return None
    try:
        return json.loads(text)
    except (TypeError, ValueError):
        return None


def read_state(path: str | Path) -> ReportData:
    """Everything a report shows from a daemon's state.

    Args:
        path: the state directory (or its ``state.db``).

    Raises:
        InputError: no state there, or not a hdeem-watch state (missing ``runs`` table).
    """
    file = state_path(path)
    db = _connect(file)
    try:
        tables = table_columns(db)
        missing = [name for name in REQUIRED_TABLES if name not in tables]
        if missing:
            raise InputError(f"{file}: not a hdeem-watch state (no {missing[0]!r} table)")
        # a run record carries the whole fit after it (its per-run list grows with the runs): leave
        # that to SQLite's JSON functions rather than parse it once per run here
        texts = [t for (t,) in db.execute(f"SELECT {_slim(db, 'record', '$.fit', '$.samples_ns')} FROM runs "
                                          "ORDER BY seq")]
        records = [r for r in (_run_record(_json(t)) for t in texts) if r is not None]
        damaged = len(texts) - len(records)
        history, pair_history = _fit_history(db, tables)
        history = _with_full_latest(db, history)
        calibrator = _json(db.execute("SELECT state FROM calibrator WHERE id = 1").fetchone()[0]) \
            if "calibrator" in tables and db.execute("SELECT count(*) FROM calibrator").fetchone()[0] else None
        stored_baselines = _stored_baselines(db, tables)
        job_records = _job_table(db, tables)
        quarantined = db.execute("SELECT count(*) FROM quarantine").fetchone()[0] if "quarantine" in tables else 0
        stored_alarms = [a for (a,) in db.execute("SELECT alarm FROM alarms ORDER BY id")] if "alarms" in tables else []
    except sqlite3.DatabaseError as error:
        raise InputError(f"{file}: cannot read the state database ({error})") from None
    finally:
        db.close()
    notes: list[str] = []
    if damaged:
        notes.append(f"{damaged} run record(s) of the state are not readable run records and are left out")
    if quarantined:
        notes.append(f"the daemon set {quarantined} damaged row(s) of its state aside (table quarantine); "
                     "they are not shown")
    spec = _spec_of(records, notes)
    fit = next((entry.fit for entry in reversed(history) if entry.fit is not None), None)
    if history and history[-1].fit is None:
        notes.append("the calibrator was reset after the last fit; the figures show the last fit before the reset")
    runs = _runs(records, spec, fit)
    channels = tuple(sorted({c for r in runs for c in r.channel_energy_j}))
    from_runs = _idle_run_baselines(records)
    # the stored baseline of an idle run is that run's point again (its time differs by the window cut)
    baselines = from_runs + [b for b in stored_baselines if not any(
        p.channel == b.channel and p.origin == b.origin and abs(p.t_ns - b.t_ns) < 60e9 for p in from_runs)]
    jobs = job_records if job_records else jobs_from_runs(records, baselines)
    settings = (calibrator or {}).get("settings") or {}
    lag = settings.get("drift_lag_s") or settings.get("half_life_s")
    groups = (calibrator or {}).get("sensor_groups")
    pair_history = {**pair_history, **_group_histories(groups)}
    pair_fits = {group: entries[-1].fit for group, entries in pair_history.items() if entries and entries[-1].fit}
    return ReportData(source=f"daemon state {file}", spec=spec, runs=tuple(runs), fit=fit,
                      fit_history=tuple(history), drift_lag_s=float(lag) if lag else None,
                      baselines=tuple(sorted(baselines, key=lambda b: (b.t_ns, b.channel))), jobs=tuple(jobs),
                      pair_fits=pair_fits, pair_history={g: tuple(e) for g, e in pair_history.items()},
                      alarms=_alarms(groups, stored_alarms), channels=channels, notes=tuple(notes))


def _group_histories(groups: Any) -> dict[str, list[FitEntry]]:
    """Each DIMM pair's fits over time from the per-group calibrators' state (the calibrator row's
    ``sensor_groups.calibrators[pair].history``: ``{"time_ns", "fit"}`` after every refit); the
    node-level entry of that state is the node fit's, kept in the ``fits`` table."""
    calibrators = groups.get("calibrators") if isinstance(groups, Mapping) else None
    out: dict[str, list[FitEntry]] = {}
    for name, state in (calibrators or {}).items():
        history = state.get("history") if isinstance(state, Mapping) else None
        if str(name) == "node" or not isinstance(history, list):
            continue
        entries = [FitEntry(t_ns=int(h.get("time_ns") or 0), run_id=None, fit=_fit(h["fit"]), row=i)
                   for i, h in enumerate(history) if isinstance(h, Mapping) and isinstance(h.get("fit"), Mapping)]
        if entries:
            out[str(name)] = entries
    return out


def _alarms(groups: Any, stored: Sequence[str]) -> tuple[dict[str, Any], ...]:
    """The drift alarms: the ``alarms`` table (every alarm ever raised) and those the calibrator
    state still holds, once each, oldest first."""
    found: dict[tuple[Any, ...], dict[str, Any]] = {}
    held = groups.get("alarms") if isinstance(groups, Mapping) else None
    for alarm in [*(_json(a) for a in stored), *(held if isinstance(held, list) else [])]:
        if isinstance(alarm, Mapping) and alarm.get("group") and alarm.get("current"):
            key = (alarm.get("group"), alarm.get("current"), alarm.get("kind"), alarm.get("time_ns"))
            found.setdefault(key, dict(alarm))
    return tuple(sorted(found.values(), key=lambda a: int(a.get("time_ns") or 0)))


def _fit_history(db: sqlite3.Connection, tables: Mapping[str, list[str]]
                 ) -> tuple[list[FitEntry], dict[str, list[FitEntry]]]:
    """The node's fit history and, when the schema has a group column, each group's."""
    if "fits" not in tables:
        return [], {}
    group_column = next((c for c in _GROUP_COLUMNS if c in tables["fits"]), None)
    fit = _slim(db, "fit", "$.runs", "$.observability.correlation")
    select = f'SELECT t_ns, run_id, {fit}, "{group_column}", id FROM fits ORDER BY id' if group_column \
        else f"SELECT t_ns, run_id, {fit}, NULL, id FROM fits ORDER BY id"
    node: list[FitEntry] = []
    groups: dict[str, list[FitEntry]] = {}
    for t_ns, run_id, text, group, row in db.execute(select):
        value = _json(text)
        if value is not None and not isinstance(value, Mapping):
            continue  # a damaged row (no fit, nor a reset's null): the daemon sets it aside at its next start
        entry = FitEntry(t_ns=int(t_ns or 0), run_id=run_id, fit=_fit(value), row=int(row))
        if group in (None, "", "node"):
            node.append(entry)
        else:
            groups.setdefault(str(group), []).append(entry)
    return node, groups


def _slim(db: sqlite3.Connection, column: str, *paths: str) -> str:
    """SQL for ``column`` without the JSON members ``paths`` (NULL for damaged JSON), or the column
    itself when this SQLite has no JSON functions."""
    if not _has_json(db):
        return column
    removed = ", ".join(f"'{p}'" for p in paths)
    return f"CASE WHEN json_valid({column}) THEN json_remove({column}, {removed}) END"


def _has_json(db: sqlite3.Connection) -> bool:
    """Whether this SQLite has the JSON functions (built in since 3.38)."""
    try:
        db.execute("SELECT json_remove('{}', '$.x')").fetchone()
    except sqlite3.OperationalError:
        return False
    return True


def _with_full_latest(db: sqlite3.Connection, history: list[FitEntry]) -> list[FitEntry]:
    """The history with the newest fit read whole (per-run details and correlation included)."""
    for i in range(len(history) - 1, -1, -1):
        if history[i].fit is not None:
            (text,) = db.execute("SELECT fit FROM fits WHERE id = ?", (history[i].row,)).fetchone()
            history[i] = FitEntry(t_ns=history[i].t_ns, run_id=history[i].run_id, fit=_fit(_json(text)),
                                  row=history[i].row)
            break
    return history


def _stored_baselines(db: sqlite3.Connection, tables: Mapping[str, list[str]]) -> list[BaselinePoint]:
    """Baselines from every ``baseline*`` table with ``channel`` and ``record`` columns."""
    out = []
    for name, columns in tables.items():
        if not name.startswith("baseline") or not {"channel", "record"} <= set(columns):
            continue
        for channel, text in db.execute(f'SELECT channel, record FROM "{name}"'):
            record = _json(text) or {}
            power = finite(record.get("power_w"))
            if is_dram_channel(str(channel)) and math.isfinite(power):
                out.append(BaselinePoint(channel=str(channel), t_ns=int(record.get("t_ns") or 0), power_w=power,
                                         spread_w=finite(record.get("spread_w")),
                                         origin=str(record.get("origin") or "stored")))
    return out


def _job_table(db: sqlite3.Connection, tables: Mapping[str, list[str]]) -> list[JobRow]:
    """Job records of a ``jobs`` table (JSON in a ``record`` column), if a newer daemon keeps one."""
    if "jobs" not in tables or "record" not in tables["jobs"]:
        return []
    jobs = []
    for (text,) in db.execute("SELECT record FROM jobs"):
        try:
            job = JobRecord.from_dict(_json(text))
        except ValueError:  # not a job record: left out
            continue
        if not math.isfinite(job.dram_energy_j):
            continue
        jobs.append(JobRow(job_id=job.job_id, node=job.node, dram_energy_j=job.dram_energy_j,
                           baseline_j=job.dram_energy_j - job.dram_above_baseline_j, window_s=job.measured_s,
                           runs=None))
    return jobs


def _run_record(value: Any) -> RunRecord | None:
    """A stored run (None: not readable as one)."""
    try:
        return RunRecord.from_dict(value)
    except ValueError:
        return None


def _spec_of(records: Sequence[RunRecord], notes: list[str]) -> Any:
    """The datasheet memspec the daemon modelled the runs with (found by its memoryId among the presets)."""
    from hdeem_watch.dram.memspec import memspec_from, preset
    from hdeem_watch.dram.presets import PRESETS

    names = {str(r.model.get("memspec")) for r in records if r.model}
    names.discard("None")
    if not names:
        notes.append("no run was modelled: the memspec is unknown")
        return None
    wanted = sorted(names)[-1]
    for name in PRESETS:
        spec = preset(name)
        if wanted in (name, spec.memory_id):
            return spec
    try:
        return memspec_from(wanted)
    except InputError:
        notes.append(f"memspec {wanted!r} is neither a preset nor a readable file: energies by component "
                     "and the calibrated memspec cannot be shown")
        return None


def _fit(value: Any) -> FitRecord | None:
    """A stored fit read by the one parser (None for none, or for JSON that is no object)."""
    return FitRecord.from_dict(value) if isinstance(value, Mapping) else None


def _runs(records: Sequence[RunRecord], spec: Any, fit: FitRecord | None) -> list[RunRow]:
    import numpy as np

    currents = model_currents(spec, fit) if spec is not None and fit is not None else None
    by_name = fit.runs_by_name() if fit is not None else {}
    out = []
    for record in records:
        measured = finite(record.dram_energy_j)
        if record.state != "done" or not measured > 0:
            continue
        model = record.model or {}
        observation = model.get("observation") or {}
        key = observation.get("name") or f"{record.run_id}:{record.name}"
        in_fit = by_name.get(str(key), {})
        calibrated = finite(in_fit.get("after_j"))
        if currents is not None and observation.get("columns"):
            vector, intercept = currents
            columns = np.asarray(observation["columns"], dtype=float)
            if columns.shape == vector.shape:
                calibrated = float(columns @ vector + finite(observation.get("constant_j")) + intercept)
        energies = {c: finite(e) for c, e in (record.energy_j or {}).items() if is_dram_channel(c)}
        figures = record.figures
        out.append(RunRow(
            run_id=record.run_id, name=record.name or record.run_id, kernel=record.kernel,
            threads=record.threads or 0, t_ns=record.t_stop_ns or 0,
            window_s=finite(record.window_s), measured_j=measured,
            datasheet_j=figures.datasheet_j, calibrated_j=calibrated,
            predicted_j=figures.predicted_j, loo_j=finite(in_fit.get("loo_j")),
            elements=record.elements or 0, repeat=record.repeat or 1,
            dimms=int(model.get("dimms") or 0), channel_energy_j=energies))
    return out


def _idle_run_baselines(records: Sequence[RunRecord]) -> list[BaselinePoint]:
    """Each finished idle run's mean power per DRAM channel: the baseline at that time."""
    out = []
    for record in records:
        if record.state != "done" or not record.moves_no_traffic:
            continue
        for channel, power in (record.mean_power_w or {}).items():
            value = finite(power)
            if is_dram_channel(channel) and math.isfinite(value):
                out.append(BaselinePoint(channel=channel, t_ns=record.t_stop_ns or 0,
                                         power_w=value, spread_w=math.nan, origin="idle-run"))
    return out


