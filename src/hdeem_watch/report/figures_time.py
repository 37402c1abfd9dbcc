"""The figures over time: residuals and leave-one-out error (3), currents with drift alarms and idle
baselines (4), and jobs (6). Times are wall-clock UTC; a RUNS.json without times uses run numbers.
"""

from __future__ import annotations

import datetime as dt
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from hdeem_watch.fit_record import CurrentFit, FitError
from hdeem_watch.report import analysis
from hdeem_watch.report.figure import ReportFigure, Table, rows
from hdeem_watch.report.records import FitEntry, ReportData, RunRow, finite
from hdeem_watch.report.style import SERIES, legend_outside, message_figure, percent_axis, pyplot, style


def utc(t_ns: int) -> dt.datetime:
    """Wall-clock ns → an aware UTC datetime (for axes and tables)."""
    return dt.datetime.fromtimestamp(t_ns / 1e9, tz=dt.UTC)


def _time_axis(ax: Any, times_ns: Sequence[int]) -> tuple[list[Any], bool]:
    """x values for ``times_ns``: UTC datetimes when every time is known, else run numbers."""
    if times_ns and all(t > 0 for t in times_ns):
        import matplotlib.dates as mdates

        locator = mdates.AutoDateLocator()
        ax.xaxis.set_major_locator(locator)
        ax.xaxis.set_major_formatter(mdates.ConciseDateFormatter(locator, tz=dt.UTC))
        ax.set_xlabel("time (UTC)")
        if min(times_ns) == max(times_ns):  # one moment: a minute either side, not years
            ax.set_xlim(utc(times_ns[0] - 60 * 10**9), utc(times_ns[0] + 60 * 10**9))
        return [utc(t) for t in times_ns], True
    ax.set_xlabel("run number")
    return list(range(1, len(times_ns) + 1)), False


def _stamp(t_ns: int) -> str:
    return utc(t_ns).strftime("%Y-%m-%d %H:%M:%S") if t_ns > 0 else "–"


def determined(history: Sequence[FitEntry]) -> tuple[list[FitEntry], int]:
    """The fits with more runs than unknowns (every current and the intercept), and how many fits
    had fewer: those match their runs exactly (in-sample errors of 1e-10 %) and predict nothing, so
    a figure of fit errors over time leaves them out."""
    kept = []
    for entry in history:
        if entry.fit is not None and (entry.fit.n_runs or 0) > len(entry.fit.currents) + 1:
            kept.append(entry)
    return kept, sum(1 for h in history if h.fit is not None) - len(kept)


def _panels(title: str, drawers: Sequence[Any], reasons: Sequence[str]) -> Any:
    """A figure of one panel per drawer (each ``drawer(ax)``), or one message panel with
    ``reasons`` when there is none: never an empty box or a degenerate axis."""
    if not drawers:
        return message_figure(title, "; ".join(reasons))
    fig, axes = pyplot().subplots(len(drawers), 1, figsize=(8.5, 0.6 + 3.0 * len(drawers)), squeeze=False)
    for drawer, ax in zip(drawers, axes[:, 0]):
        drawer(ax)
    axes[0, 0].set_title(title if axes[0, 0].get_title() == "" else axes[0, 0].get_title())
    fig.tight_layout()
    return fig


def residuals_figure(data: ReportData) -> ReportFigure:
    """Figure 3: residual of each run over time (calibrated, out-of-sample, leave-one-out) and the fit errors."""
    title = "Residuals per run over time, and the leave-one-out error"
    how = ("Top: each run's model error against its measurement — with the latest fit, with the fit from before "
           "the run (a true prediction) and left out of the fit; bottom: the fits' mean errors as runs came in "
           "(fits with more runs than unknowns).")
    runs = [r for r in data.runs if math.isfinite(r.calibrated_j)]
    history, underdetermined = determined([h for h in data.fit_history if h.fit is not None])
    drawers: list[Any] = []
    reasons: list[str] = []
    missing: list[str] = []
    if len(runs) >= 2:
        drawers.append(lambda ax: _draw_residuals(ax, runs, title))
    else:
        reasons.append("no calibrated runs" if not runs else "one calibrated run (its error is in the table)")
        missing.append("calibration" if not runs else "residuals over time (one run)")
    if len(history) >= 2:
        drawers.append(lambda ax: _draw_fit_errors(ax, history))
    else:
        reason = f"{len(history) or 'no'} fit{'' if len(history) == 1 else 's'} with more runs than unknowns"
        reasons.append(reason + (f" ({underdetermined} with fewer left out)" if underdetermined else ""))
        missing.append(f"fit errors over time ({reason})")
    fig = _panels(title, drawers, reasons)
    table_history = []
    for h in data.fit_history:
        if h.fit is not None:
            error = h.fit.error
            table_history.append((_stamp(h.t_ns), h.run_id, h.fit.n_runs, error.before * 100, error.after * 100,
                                  error.loo * 100))
    tables = {
        "residual per run": Table(
            ("run", "kernel", "threads", "end (UTC)", "measured J", "latest fit error %", "fit-before error %",
             "leave-one-out error %"),
            rows([(r.run_id, r.kernel, r.threads or None, _stamp(r.t_ns), r.measured_j, r.error_pct("calibrated_j"),
                   r.error_pct("predicted_j"), r.error_pct("loo_j")) for r in runs])),
        "fit errors over time": Table(("time (UTC)", "after run", "runs", "datasheet error %", "calibrated error %",
                                       "leave-one-out error %"), rows(table_history)),
    }
    return ReportFigure("fig3-residuals", title, how, fig, tables, tuple(missing))


def _draw_residuals(ax: Any, runs: Sequence[RunRow], title: str) -> None:
    x, _ = _time_axis(ax, [r.t_ns for r in runs])
    series = (("latest fit", "calibrated_j", SERIES["calibrated"].marker, "#0072B2", "full"),
              ("fit before the run", "predicted_j", "o", "#D55E00", "none"),
              ("leave-one-out", "loo_j", "D", "#009E73", "none"))
    for label, field, marker, color, fill in series:
        values = [r.error_pct(field) for r in runs]
        if any(math.isfinite(v) for v in values):
            ax.plot(x, values, linestyle="none", marker=marker, color=color, fillstyle=fill, label=label,
                    markersize=5)
    ax.axhline(0.0, color="#333333", linewidth=0.8)
    percent_axis(ax, "model − measured (% of measured)")
    ax.set_title(title)
    legend_outside(ax)


def _draw_fit_errors(ax: Any, history: Sequence[FitEntry]) -> None:
    hx, _ = _time_axis(ax, [h.t_ns for h in history])
    errors = [h.fit.error if h.fit is not None else FitError() for h in history]
    for label, values, k in (("calibrated (in sample)", [e.after * 100 for e in errors], 0),
                             ("leave-one-out", [e.loo * 100 for e in errors], 2),
                             ("datasheet", [e.before * 100 for e in errors], 4)):
        s = style(k)
        ax.plot(hx, values, marker=s.marker, color=s.color, label=label, markersize=4, linewidth=1.0)
    ax.set_yscale("log")
    ax.set_ylabel("mean |error| of the fit (%)")
    legend_outside(ax)


def aging_figure(data: ReportData) -> ReportFigure:
    """Figure 4: currents over time with drift alarms, and each DIMM pair's idle baseline over time."""
    title = "Aging: currents over time with drift alarms, and idle baseline per DIMM pair"
    how = ("Top: each calibrated current after every refit with its 95 % band; a black ✕ marks a drift alarm "
           "(named by its DIMM pair and current). Bottom: each DIMM pair's idle power each time it was "
           "measured — a rising line is a pair drawing more.")
    missing: list[str] = []
    history = [h for h in data.fit_history if h.fit is not None]
    names = list(history[-1].fit.currents) if history and history[-1].fit is not None else []
    drawers: list[Any] = []
    reasons: list[str] = []
    if len(history) >= 2:
        drawers.append(lambda ax: _draw_currents(ax, data, history, names, title))
    else:
        reason = "no fit history" if not history else "one fit (its currents and intervals are in Figure 2)"
        reasons.append(reason)
        missing.append(f"currents over time ({reason})")
    if not data.pair_history and data.drift_lag_s is None and not data.alarms:
        missing.append("drift alarms (no half-life or drift lag and no per-pair detectors: there is no "
                       "reference to drift from)")
    if len({b.t_ns for b in data.baselines}) >= 2:
        drawers.append(lambda ax: _draw_baselines(ax, data))
    else:
        reason = "no idle baselines" if not data.baselines else "one idle baseline measurement (in the table)"
        reasons.append(reason)
        missing.append(f"idle baselines over time ({reason})")
    fig = _panels(title, drawers, reasons)
    flags = analysis.drift_flags(history, data.drift_lag_s)
    table_currents = [(_stamp(h.t_ns), h.run_id,
                       *[_current(h, n).calibrated_a * 1e3 for n in names],
                       ", ".join(n for n, v in f.items() if v) or "none") for h, f in zip(history, flags)]
    tables = {
        "currents over time (mA)": Table(("time (UTC)", "after run", *[f"{n} mA" for n in names], "drift alarm"),
                                         rows(table_currents)),
        "drift alarms": Table(("time (UTC)", "pair", "current", "kind", "direction", "statistic", "threshold"),
                              rows([(_stamp(int(a.get("time_ns") or 0)), a.get("group"), a.get("current"),
                                     a.get("kind"), a.get("direction"), finite(a.get("statistic")),
                                     finite(a.get("threshold"))) for a in data.alarms])),
        "idle baselines": Table(("time (UTC)", "pair", "power W", "spread W", "origin"),
                                rows([(_stamp(b.t_ns), b.channel, b.power_w, b.spread_w, b.origin)
                                      for b in data.baselines])),
    }
    return ReportFigure("fig4-aging", title, how, fig, tables, tuple(missing))


def _current(entry: FitEntry, name: str) -> CurrentFit:
    """Current ``name`` of the entry's fit (all unknown when the fit lacks it)."""
    fit = entry.fit
    return fit.currents.get(name, CurrentFit(name)) if fit is not None else CurrentFit(name)


def _draw_currents(ax: Any, data: ReportData, history: Sequence[FitEntry], names: Sequence[str], title: str) -> None:
    """The node fit's currents over time with their bands, the node-level drift flags and the
    daemon's per-pair alarms."""
    x, dated = _time_axis(ax, [h.t_ns for h in history])
    flags = analysis.drift_flags(history, data.drift_lag_s)
    alarm_x, alarm_y = [], []
    for k, name in enumerate(names):
        entries = [_current(h, name) for h in history]
        values = np.array([e.calibrated_a * 1e3 for e in entries])
        ci = np.array([[v * 1e3 for v in e.ci95_a] for e in entries])
        s = style(k)
        band = np.isfinite(ci).all(axis=1)
        ax.plot(x, values, marker=s.marker, color=s.color, label=name.upper(), markersize=5, linewidth=1.0)
        if band.any():
            ax.fill_between([xi for xi, b in zip(x, band) if b], ci[band, 0], ci[band, 1], color=s.color,
                            alpha=0.12, linewidth=0)
        for i, f in enumerate(flags):
            if f.get(name):
                alarm_x.append(x[i])
                alarm_y.append(values[i])
    if alarm_x:
        ax.plot(alarm_x, alarm_y, linestyle="none", marker="X", color="#000000", markersize=10,
                label="drift (node fit)")
    pair_alarms = [a for a in data.alarms if dated and int(a.get("time_ns") or 0) > 0]
    if pair_alarms:
        import matplotlib.dates as mdates
        import matplotlib.transforms as mtransforms

        at_top = mtransforms.blended_transform_factory(ax.transData, ax.transAxes)
        when = [float(mdates.date2num(utc(int(a["time_ns"])))) for a in pair_alarms]
        ax.plot(when, [0.96] * len(pair_alarms), linestyle="none", marker="X", color="#000000", markersize=10,
                transform=at_top, label="drift alarm (pair)")
        for a, t in list(zip(pair_alarms, when))[:6]:
            ax.annotate(f"{a.get('group')} {a.get('current')}", (t, 0.96), xycoords=at_top,
                        xytext=(-4, -14), textcoords="offset points", fontsize=8, ha="right")
    ax.set_ylabel("calibrated current (mA)")
    legend_outside(ax)
    scope = "node-level fit" + (f"; {len(data.pair_fits)} per-DIMM-pair fits in Figure 2" if data.pair_fits
                                else "; no per-DIMM-pair fits in this input")
    detectors = f"{len(data.alarms)} pair alarm(s)" if data.pair_history or data.alarms else (
        "drift alarms off: no half-life" if data.drift_lag_s is None else
        f"drift reference {data.drift_lag_s / 3600:g} h earlier; {len(alarm_x)} alarm(s)")
    ax.set_title(f"{title}\n({scope}; {detectors})")


def _draw_baselines(ax: Any, data: ReportData) -> None:
    channels = sorted({b.channel for b in data.baselines})
    bx, _ = _time_axis(ax, [b.t_ns for b in data.baselines])
    for k, channel in enumerate(channels):
        s = style(k)
        points = [(xi, b) for xi, b in zip(bx, data.baselines) if b.channel == channel]
        for origin, fill in (("idle-run", "full"), ("quiet", "none"), ("stored", "left")):
            chosen = [(xi, b.power_w) for xi, b in points if b.origin == origin]
            if chosen:
                label = channel if origin == "idle-run" else f"{channel} ({origin})"
                ax.plot([c[0] for c in chosen], [c[1] for c in chosen], marker=s.marker, color=s.color,
                        fillstyle=fill, label=label, linewidth=1.0 if origin == "idle-run" else 0, markersize=5)
    ax.set_ylabel("idle power per DIMM pair (W)")
    legend_outside(ax)


def jobs_figure(data: ReportData) -> ReportFigure:
    """Figure 6: DRAM energy per job and node, and the part above the idle baseline."""
    plt = pyplot()
    title = "Jobs: DRAM energy per job and node, above the idle baseline"
    how = ("Each pair of bars is one job on one node: all the DRAM energy its runs used, and the part above what "
           "the idle DIMMs would have used in the same time.")
    if not data.jobs:
        fig = message_figure(title, "no job records: no run carried a job id (runs announced inside a SLURM job do)")
        return ReportFigure("fig6-jobs", title, how, fig, missing=("job records",))
    fig, ax = plt.subplots(figsize=(8.5, 3.8))
    x = np.arange(len(data.jobs))
    total, above = style(0), style(1)
    ax.bar(x - 0.2, [j.dram_energy_j for j in data.jobs], 0.4, color=total.color, hatch=total.hatch,
           edgecolor="#333333", linewidth=0.4, label="DRAM energy")
    ax.bar(x + 0.2, [j.above_baseline_j for j in data.jobs], 0.4, color=above.color, hatch=above.hatch,
           edgecolor="#333333", linewidth=0.4, label="above idle baseline")
    ax.set_xticks(x, [f"{j.job_id}\n{j.node}" for j in data.jobs])
    ax.set_ylabel("DRAM energy (J)")
    ax.set_title(title)
    legend_outside(ax)
    fig.tight_layout()
    table = Table(("job", "node", "runs", "window s", "DRAM energy J", "baseline J", "above baseline J"),
                  rows([(j.job_id, j.node, j.runs, j.window_s, j.dram_energy_j, j.baseline_j, j.above_baseline_j)
                        for j in data.jobs]))
    return ReportFigure("fig6-jobs", title, how, fig, {"jobs": table})
