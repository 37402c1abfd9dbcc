"""The figures over time: residuals and leave-one-out error (3), currents with drift alarms and idle
baselines (4), and jobs (6). Times are wall-clock UTC; a RUNS.json without times uses run numbers.
"""

from __future__ import annotations

import datetime as dt
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from hdeem_watch.report import analysis
from hdeem_watch.report.figure import ReportFigure, Table, rows
from hdeem_watch.report.records import ReportData, finite
from hdeem_watch.report.style import SERIES, legend_outside, no_data, percent_axis, pyplot, style


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


def residuals_figure(data: ReportData) -> ReportFigure:
    """Figure 3: residual of each run over time (calibrated, out-of-sample, leave-one-out) and the fit errors."""
    plt = pyplot()
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8.5, 6.0))
    title = "Residuals per run over time, and the leave-one-out error"
    how = ("Top: each run's model error against its measurement — with the latest fit, with the fit from before "
           "the run (a true prediction) and left out of the fit; bottom: the fits' mean errors as runs came in.")
    runs = [r for r in data.runs if math.isfinite(r.calibrated_j)]
    if not runs:
        no_data(top, "no calibrated runs")
        no_data(bottom, "no fit history")
        return ReportFigure("fig3-residuals", title, how, fig, missing=("calibration",))
    x, _ = _time_axis(top, [r.t_ns for r in runs])
    series = (("latest fit", "calibrated_j", SERIES["calibrated"].marker, "#0072B2", "full"),
              ("fit before the run", "predicted_j", "o", "#D55E00", "none"),
              ("leave-one-out", "loo_j", "D", "#009E73", "none"))
    for label, field, marker, color, fill in series:
        values = [r.error_pct(field) for r in runs]
        if any(math.isfinite(v) for v in values):
            top.plot(x, values, linestyle="none", marker=marker, color=color, fillstyle=fill, label=label,
                     markersize=5)
    top.axhline(0.0, color="#333333", linewidth=0.8)
    percent_axis(top, "model − measured (% of measured)")
    top.set_title(title)
    legend_outside(top)
    history = [h for h in data.fit_history if h.fit is not None]
    table_history = []
    if history:
        hx, _ = _time_axis(bottom, [h.t_ns for h in history])
        for label, key, k in (("calibrated (in sample)", "after", 0), ("leave-one-out", "loo", 2),
                              ("datasheet", "before", 4)):
            values = [finite(((h.fit or {}).get("error") or {}).get(key)) * 100 for h in history]
            s = style(k)
            bottom.plot(hx, values, marker=s.marker, color=s.color, label=label, markersize=4, linewidth=1.0)
        bottom.set_yscale("log")
        bottom.set_ylabel("mean |error| of the fit (%)")
        legend_outside(bottom)
        for h in history:
            errors = (h.fit or {}).get("error") or {}
            table_history.append((_stamp(h.t_ns), h.run_id, (h.fit or {}).get("n_runs"),
                                  finite(errors.get("before")) * 100, finite(errors.get("after")) * 100,
                                  finite(errors.get("loo")) * 100))
    else:
        no_data(bottom, "no fit history")
    fig.tight_layout()
    tables = {
        "residual per run": Table(
            ("run", "kernel", "threads", "end (UTC)", "measured J", "latest fit error %", "fit-before error %",
             "leave-one-out error %"),
            rows([(r.run_id, r.kernel, r.threads or None, _stamp(r.t_ns), r.measured_j, r.error_pct("calibrated_j"),
                   r.error_pct("predicted_j"), r.error_pct("loo_j")) for r in runs])),
        "fit errors over time": Table(("time (UTC)", "after run", "runs", "datasheet error %", "calibrated error %",
                                       "leave-one-out error %"), rows(table_history)),
    }
    return ReportFigure("fig3-residuals", title, how, fig, tables, () if history else ("fit history",))


def aging_figure(data: ReportData) -> ReportFigure:
    """Figure 4: currents over time with drift alarms, and each DIMM pair's idle baseline over time."""
    plt = pyplot()
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8.5, 6.4))
    title = "Aging: currents over time with drift alarms, and idle baseline per DIMM pair"
    how = ("Top: each calibrated current after every refit with its 95 % band; a black ✕ marks a drift alarm. "
           "Bottom: each DIMM pair's idle power each time it was measured — a rising line is a pair drawing more.")
    missing: list[str] = []
    history = [h for h in data.fit_history if h.fit is not None]
    flags = analysis.drift_flags(history, data.drift_lag_s)
    scope = "node-level fit" + ("" if data.pair_fits else "; no per-DIMM-pair fits in this input")
    if not data.pair_fits:
        missing.append("per-DIMM-pair current histories (node-level only)")
    if data.drift_lag_s is None:
        missing.append("drift alarms (no half-life or drift lag: every run is kept, so there is no reference fit to drift from)")
    table_currents = []
    if history:
        x, _ = _time_axis(top, [h.t_ns for h in history])
        names = list((history[-1].fit or {}).get("currents") or {})
        alarm_x, alarm_y = [], []
        for k, name in enumerate(names):
            entries = [((h.fit or {}).get("currents") or {}).get(name) or {} for h in history]
            values = np.array([finite(e.get("calibrated")) * 1e3 for e in entries])
            ci = np.array([[finite(v) * 1e3 for v in (e.get("ci95") or [None, None])] for e in entries])
            s = style(k)
            band = np.isfinite(ci).all(axis=1)
            top.plot(x, values, marker=s.marker, color=s.color, label=name.upper(), markersize=5, linewidth=1.0)
            if band.any() and len(history) > 1:  # one fit: its intervals are in figure 2
                top.fill_between([xi for xi, b in zip(x, band) if b], ci[band, 0], ci[band, 1], color=s.color,
                                 alpha=0.12, linewidth=0)
            for i, f in enumerate(flags):
                if f.get(name):
                    alarm_x.append(x[i])
                    alarm_y.append(values[i])
        if alarm_x:
            top.plot(alarm_x, alarm_y, linestyle="none", marker="X", color="#000000", markersize=10,
                     label="drift alarm")
        top.set_ylabel("calibrated current (mA)")
        legend_outside(top)
        lo = np.nanmin([finite(((h.fit or {}).get("currents") or {}).get(n, {}).get("calibrated")) * 1e3
                        for h in history for n in names] or [0.0])
        hi = np.nanmax([finite(((h.fit or {}).get("currents") or {}).get(n, {}).get("calibrated")) * 1e3
                        for h in history for n in names] or [1.0])
        if math.isfinite(lo) and math.isfinite(hi):
            top.set_ylim(max(0.0, lo - 0.2 * (hi - lo + 1)), hi + 0.3 * (hi - lo + 1))
        for h, f in zip(history, flags):
            cur = (h.fit or {}).get("currents") or {}
            table_currents.append((_stamp(h.t_ns), h.run_id,
                                   *[finite((cur.get(n) or {}).get("calibrated")) * 1e3 for n in names],
                                   ", ".join(n for n, v in f.items() if v) or "none"))
        drift_note = "drift alarms off: no half-life" if data.drift_lag_s is None else \
            f"drift reference {data.drift_lag_s / 3600:g} h earlier; {len(alarm_x)} alarm(s)"
        top.set_title(f"{title}\n({scope}; {drift_note})")
    else:
        names = []
        no_data(top, "no fit history in this input")
        top.set_title(title)
        missing.append("fit history")
    channels = sorted({b.channel for b in data.baselines})
    if channels:
        bx, _ = _time_axis(bottom, [b.t_ns for b in data.baselines])
        for k, channel in enumerate(channels):
            s = style(k)
            points = [(xi, b) for xi, b in zip(bx, data.baselines) if b.channel == channel]
            for origin, fill in (("idle-run", "full"), ("quiet", "none"), ("stored", "left")):
                chosen = [(xi, b.power_w) for xi, b in points if b.origin == origin]
                if chosen:
                    label = channel if origin == "idle-run" else f"{channel} ({origin})"
                    bottom.plot([c[0] for c in chosen], [c[1] for c in chosen], marker=s.marker, color=s.color,
                                fillstyle=fill, label=label, linewidth=1.0 if origin == "idle-run" else 0,
                                markersize=5)
        bottom.set_ylabel("idle power per DIMM pair (W)")
        legend_outside(bottom)
    else:
        no_data(bottom, "no idle baselines in this input")
        missing.append("idle baselines")
    fig.tight_layout()
    tables = {
        "currents over time (mA)": Table(("time (UTC)", "after run", *[f"{n} mA" for n in names], "drift alarm"),
                                         rows(table_currents)),
        "idle baselines": Table(("time (UTC)", "pair", "power W", "spread W", "origin"),
                                rows([(_stamp(b.t_ns), b.channel, b.power_w, b.spread_w, b.origin)
                                      for b in data.baselines])),
    }
    return ReportFigure("fig4-aging", title, how, fig, tables, tuple(missing))


def jobs_figure(data: ReportData) -> ReportFigure:
    """Figure 6: DRAM energy per job and node, and the part above the idle baseline."""
    plt = pyplot()
    title = "Jobs: DRAM energy per job and node, above the idle baseline"
    how = ("Each pair of bars is one job on one node: all the DRAM energy its runs used, and the part above what "
           "the idle DIMMs would have used in the same time.")
    fig, ax = plt.subplots(figsize=(8.5, 3.8))
    if not data.jobs:
        no_data(ax, "no job records: no run carried a job id (runs announced inside a SLURM job do)")
        ax.set_title(title)
        return ReportFigure("fig6-jobs", title, how, fig, missing=("job records",))
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
