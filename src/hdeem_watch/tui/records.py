"""Reading the daemon's JSON records (runs, fits, baselines) into the UI's snapshot views.

The wire protocol carries runs, fits and baselines as JSON objects (docs/protocol.md). Runs are
read by the one parser of run records (:meth:`hdeem_watch.run_record.RunRecord.from_dict`); fits
and baselines here. These functions turn them into :mod:`hdeem_watch.tui.snapshot` views,
tolerating missing fields (shown as unknown) so that a newer daemon with more fields, or an older
one with fewer, still displays.
Pure functions; no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from hdeem_watch.channels import DRAM_CHANNELS
from hdeem_watch.fit_record import FitRecord
from hdeem_watch.job_record import JobRecord
from hdeem_watch.run_record import RunRecord
from hdeem_watch.tui.group_views import group_views
from hdeem_watch.tui.snapshot import CalibView, CommandRates, CurrentView, RunView


@dataclass(frozen=True)
class SimCurrentView(CurrentView):
    """A calibrated current of a simulated node: ``truth_a`` is the *effective* truth the fit can
    recover (core truth incl. the I/O energy per burst and sensor offsets, the sim's
    ``effective_currents_a``), ``truth_core_a`` the core truth (``mean_currents_a``)."""

    truth_core_a: float = math.nan


def num(value: Any) -> float:
    """A JSON number as float; None, strings and other types are NaN (unknown)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return math.nan
    return float(value)


def measured_dram_j(record: RunRecord) -> float:
    """The run's measured DRAM energy: its total, else the sum over the DIMM-pair channels."""
    total = record.dram_energy_j
    if total is not None and math.isfinite(total):
        return total
    per_channel = record.energy_j or {}
    values = [per_channel[name] for name in DRAM_CHANNELS if name in per_channel]
    if values and all(math.isfinite(v) for v in values):
        return float(sum(values))
    return math.nan


def run_view(record: RunRecord, *, running: bool = False, elapsed_s: float = math.nan,
             history: bool = False) -> RunView:
    """A :class:`RunView` of a run record (of the ``run`` topic or ``runs.list``; ``history``: stored
    before the UI connected)."""
    duration = math.nan if record.window_s is None else record.window_s
    if running and math.isfinite(elapsed_s):
        duration = elapsed_s
    figures = record.figures
    return RunView(
        run_id=record.run_id,
        name=record.name or record.kernel,
        kernel=record.kernel,
        threads=record.threads or 0,
        duration_s=duration,
        measured_j=math.nan if running else measured_dram_j(record),
        model_datasheet_j=figures.datasheet_j,
        model_calibrated_j=figures.calibrated_j,
        running=running,
        simulated=record.simulated,
        history=history,
    )


def run_record(value: Any) -> RunRecord | None:
    """The run record a message carries (None: not one, e.g. from a daemon this UI cannot read)."""
    try:
        return RunRecord.from_dict(value)
    except ValueError:
        return None


def job_record(value: Any) -> JobRecord | None:
    """A job record (or summary) from a message, None when it is no job record."""
    try:
        return JobRecord.from_dict(value)
    except ValueError:
        return None


def _current_values(obj: Any) -> dict[str, float]:
    """``{name: amperes}`` from ``{name: number}``, ``{name: {"calibrated": x}}`` or per-DIMM nesting."""
    if not isinstance(obj, Mapping):
        return {}
    for key in ("mean_currents_a", "currents_a", "currents"):
        if isinstance(obj.get(key), Mapping):
            return _current_values(obj[key])
    out: dict[str, float] = {}
    nested: list[dict[str, float]] = []
    for key, value in obj.items():
        if isinstance(value, int | float) and not isinstance(value, bool) and str(key).lower().startswith(("idd", "ipp")):
            out[str(key).lower()] = float(value)
        elif isinstance(value, Mapping):
            if "calibrated" in value:
                out[str(key).lower()] = num(value.get("calibrated"))
            else:
                inner = _current_values(value)
                if inner:
                    nested.append(inner)
    if not out and nested:  # per DIMM: the mean over DIMMs
        names = set().union(*nested)
        for name in names:
            values = [d[name] for d in nested if name in d and math.isfinite(d[name])]
            out[name] = sum(values) / len(values) if values else math.nan
    return out


def history_series(history: Iterable[Any]) -> dict[str, list[float]]:
    """Per current, the fitted values over time (oldest first) from the calib ``history`` list."""
    series: dict[str, list[float]] = {}
    for entry in history:
        fit: Any = entry
        if isinstance(entry, Sequence) and not isinstance(entry, str) and len(entry) == 2:
            fit = entry[1]
        elif isinstance(entry, Mapping) and isinstance(entry.get("fit"), Mapping):
            fit = entry["fit"]
        for name, value in _current_values(fit).items():
            series.setdefault(name, []).append(value)
    return series


def _suggestion(value: Any) -> str:
    if isinstance(value, str):
        return value
    if isinstance(value, Sequence) and value:
        head = value[0]
        if isinstance(head, Sequence) and not isinstance(head, str) and head:
            return str(head[0])
        if isinstance(head, Mapping):
            return str(head.get("name", ""))
        return str(head)
    if isinstance(value, Mapping):
        return str(value.get("name", ""))
    return ""


def calib_view(body: Mapping[str, Any], *, history_len: int = 40) -> CalibView:
    """A :class:`CalibView` from a ``calib`` message body (or the ``calib.get`` result)."""
    fit = FitRecord.from_dict(body["fit"]) if isinstance(body.get("fit"), Mapping) else None
    truth_raw = body.get("truth")
    truth = _current_values(truth_raw) if isinstance(truth_raw, Mapping) else {}
    truth_core: dict[str, float] = {}
    counted = fit is not None and fit.commands == "counted"  # a fit of counted windows recovers other effective values
    key = "counted_currents_a" if counted and isinstance(truth_raw, Mapping) and \
        isinstance(truth_raw.get("counted_currents_a"), Mapping) else "effective_currents_a"
    if isinstance(truth_raw, Mapping) and isinstance(truth_raw.get(key), Mapping):
        truth_core = truth
        truth = _current_values(truth_raw[key])
    simulated = bool(truth) or bool(isinstance(truth_raw, Mapping) and truth_raw.get("simulated"))
    history_raw = body.get("history")
    series = history_series(history_raw if isinstance(history_raw, list) else [])
    suggestion = _suggestion(body.get("suggested_next") or body.get("suggest") or body.get("next")
                             or (fit.extra.get("suggested_next") if fit is not None else None))
    model_error = str(body.get("model_error") or "")
    groups, alarms = group_views(body)
    if fit is None:
        return CalibView(simulated=simulated, suggested_next=suggestion, model_error=model_error, groups=groups,
                         alarms=alarms)
    currents: list[CurrentView] = []
    for cur in fit.currents.values():
        fields: dict[str, Any] = {
            "name": cur.name.lower(), "datasheet_a": cur.datasheet_a, "calibrated_a": cur.calibrated_a,
            "ci95_a": cur.half_width_a, "identifiable": bool(cur.identifiable),
            "truth_a": truth.get(cur.name.lower(), math.nan),
            "history_a": tuple(series.get(cur.name.lower(), [])[-history_len:]),
        }
        if truth_core:
            currents.append(SimCurrentView(**fields, truth_core_a=truth_core.get(cur.name.lower(), math.nan)))
        else:
            currents.append(CurrentView(**fields))
    return CalibView(
        determined=fit.determined,
        currents=tuple(currents),
        error_before=fit.error.before,
        error_after=fit.error.after,
        error_loo=fit.error.loo,
        n_runs=fit.n_runs or 0,
        suggested_next=suggestion,
        simulated=simulated,
        model_error=model_error,
        groups=groups,
        alarms=alarms,
    )


def sensor_command_rates(body: Mapping[str, Any]) -> dict[str, CommandRates]:
    """Per DRAM power channel, the command rates of the IMC channels it measures (a ``counters``
    message body: rates summed, the power-down share averaged; unknown stays NaN).

    >>> body = {"channels": {"S0.imc0": {"act_per_s": 1.0, "rd_per_s": 4.0, "wr_per_s": 2.0,
    ...                                  "powerdown_share": 0.5, "sensor": "DDR_AB"},
    ...                      "S0.imc1": {"act_per_s": 3.0, "rd_per_s": None, "wr_per_s": 2.0,
    ...                                  "powerdown_share": 0.1, "sensor": "DDR_AB"}}}
    >>> rates = sensor_command_rates(body)["DDR_AB"]
    >>> rates.act_per_s, math.isnan(rates.rd_per_s), round(rates.powerdown_share, 2)
    (4.0, True, 0.3)
    """
    channels = body.get("channels")
    by_sensor: dict[str, list[Mapping[str, Any]]] = {}
    if isinstance(channels, Mapping):
        for values in channels.values():
            if isinstance(values, Mapping) and isinstance(values.get("sensor"), str):
                by_sensor.setdefault(values["sensor"], []).append(values)
    out = {}
    for sensor, rows in by_sensor.items():
        shares = [num(r.get("powerdown_share")) for r in rows]
        act, rd, wr = (float(sum(num(r.get(key)) for r in rows)) for key in ("act_per_s", "rd_per_s", "wr_per_s"))
        out[sensor] = CommandRates(act, rd, wr, powerdown_share=float(sum(shares) / len(shares)))
    return out
