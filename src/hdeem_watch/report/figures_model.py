"""The model figures: energy per kernel and thread count (1), currents (2), energy by component (5).

Each builder takes :class:`~hdeem_watch.report.records.ReportData` and returns a
:class:`~hdeem_watch.report.figure.ReportFigure`; with nothing to draw the figure says so.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from hdeem_watch.fit_record import CurrentFit
from hdeem_watch.report import analysis
from hdeem_watch.report.figure import ReportFigure, Table, rows
from hdeem_watch.report.records import ReportData
from hdeem_watch.report.style import SERIES, legend_outside, message_figure, percent_axis, pyplot, style


def energy_figure(data: ReportData) -> ReportFigure:
    """Figure 1: measured vs datasheet-model vs calibrated-model energy per kernel and thread count."""
    groups = analysis.energy_groups(data.runs)
    title = "Energy per kernel and thread count: measured, datasheet model, calibrated model"
    how = ("Each group of bars is the mean DRAM energy of a kernel's runs at one thread count; the lower panel "
           "is each model's error against the measurement (0 % = exact).")
    if not groups:
        return ReportFigure("fig1-energy", title, how, message_figure(title, "no finished runs"), missing=("runs",))
    fig, table = measured_vs_models(groups, title)
    missing = () if data.fit is not None else ("calibration (no fit yet)",)
    return ReportFigure("fig1-energy", title, how, fig, {"mean energy per kernel and thread count": table}, missing)


def measured_vs_models(groups: Sequence[analysis.EnergyGroup], title: str) -> tuple[Any, Table]:
    """The measured-vs-models figure of ``groups`` (at least one): mean energies as bars above, each
    model's error against the measurement below; and its table."""
    plt = pyplot()
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(max(7.0, 0.42 * len(groups) + 2), 6.4), sharex=True,
                                      gridspec_kw={"height_ratios": (3, 2)})
    x = np.arange(len(groups))
    width = 0.27
    for k, (name, values) in enumerate((("measured", [g.measured_j for g in groups]),
                                       ("datasheet", [g.datasheet_j for g in groups]),
                                       ("calibrated", [g.calibrated_j for g in groups]))):
        s = SERIES[name]
        top.bar(x + (k - 1) * width, values, width, label=f"{name}" + (" model" if k else ""), color=s.color,
                hatch=s.hatch, edgecolor="white" if k == 0 else "#333333", linewidth=0.4)
    top.set_ylabel("DRAM energy per run (J)")
    legend_outside(top)
    top.set_title(title)
    for name, values in (("datasheet", [g.datasheet_error_pct for g in groups]),
                         ("calibrated", [g.calibrated_error_pct for g in groups])):
        s = SERIES[name]
        bottom.plot(x, values, linestyle="none", marker=s.marker, color=s.color, label=f"{name} model",
                    markersize=6, markeredgecolor="#333333", markeredgewidth=0.5)
    bottom.axhline(0.0, color="#333333", linewidth=0.8)
    percent_axis(bottom, "error vs measured (%)")
    errors = [v for g in groups for v in (g.datasheet_error_pct, g.calibrated_error_pct) if math.isfinite(v)]
    if errors:  # room above and below the extreme points on the symmetric-log axis
        bottom.set_ylim(min(-2.0, 2.0 * min(errors)), max(2.0, 2.0 * max(errors)))
    legend_outside(bottom)
    bottom.set_xticks(x, [f"{g.label}" + (f" ×{g.n}" if g.n > 1 else "") for g in groups], rotation=60,
                      ha="right")
    fig.tight_layout()
    table = Table(("kernel", "threads", "runs", "measured J", "datasheet J", "calibrated J", "datasheet error %",
                   "calibrated error %"),
                  rows([(g.kernel, g.threads or None, g.n, g.measured_j, g.datasheet_j, g.calibrated_j,
                         g.datasheet_error_pct, g.calibrated_error_pct) for g in groups]))
    return fig, table


def currents_figure(data: ReportData) -> ReportFigure:
    """Figure 2: datasheet vs calibrated current per IDD with 95 % intervals (node; pairs when fitted)."""
    plt = pyplot()
    title = "Currents: datasheet vs calibrated, with 95 % intervals"
    how = ("For each calibrated current the hatched bar is the datasheet value and the solid bar the calibrated "
           "one with its 95 % interval; 'weak' marks a current these runs do not determine.")
    fits = {"node": data.fit, **dict(data.pair_fits)} if data.fit is not None else dict(data.pair_fits)
    missing: list[str] = []
    if not data.pair_fits:
        missing.append("per-DIMM-pair fits (this input has node-level fits only)")
    if not fits:
        fig = message_figure(title, "no calibration yet: no fit in this state")
        return ReportFigure("fig2-currents", title, how, fig, missing=("calibration", *missing))
    fig, ax = plt.subplots(figsize=(8.5, 4.2))
    first = next(iter(fits.values()))
    names = list(first.currents)
    x = np.arange(len(names))
    bars = 1 + len(fits)
    width = 0.8 / bars
    datasheet = [first.currents[n].datasheet_a * 1e3 for n in names]
    s = SERIES["datasheet"]
    ax.bar(x - 0.4 + width / 2, datasheet, width, color=s.color, hatch=s.hatch, edgecolor="#333333", linewidth=0.4,
           label="datasheet")
    table_rows = []
    for k, (group, fit) in enumerate(fits.items(), start=1):
        entries = [fit.currents.get(n, CurrentFit(n)) for n in names]
        values = np.array([e.calibrated_a * 1e3 for e in entries])
        ci = np.array([[v * 1e3 for v in e.ci95_a] for e in entries])
        s = SERIES["calibrated"] if group == "node" else style(k)
        low = np.where(np.isfinite(ci[:, 0]), values - ci[:, 0], 0.0)
        high = np.where(np.isfinite(ci[:, 1]), ci[:, 1] - values, 0.0)
        ax.bar(x - 0.4 + width * (k + 0.5), values, width, color=s.color, hatch=s.hatch, edgecolor="#333333",
               linewidth=0.4, yerr=np.vstack([np.clip(low, 0, None), np.clip(high, 0, None)]), capsize=3,
               error_kw={"elinewidth": 1.0, "ecolor": "#000000"},
               label="calibrated (node)" if group == "node" else f"calibrated ({group})")
        for j, name in enumerate(names):
            table_rows.append((group, name, datasheet[j], values[j], ci[j, 0], ci[j, 1],
                               bool(entries[j].identifiable), entries[j].at_bound))
    weak = {n for n in names if not first.currents[n].identifiable}
    ax.set_xticks(x, [n.upper() + (" (weak)" if n in weak else "") for n in names])
    ax.set_ylabel("current per device (mA)")
    scope = ("node-level fit" + (f" and {len(data.pair_fits)} per-DIMM-pair fits" if data.pair_fits
                                 else "; no per-DIMM-pair fits in this input"))
    ax.set_title(f"{title}\n({scope})")
    legend_outside(ax)
    fig.tight_layout()
    table = Table(("fit", "current", "datasheet mA", "calibrated mA", "95 % low mA", "95 % high mA", "determined",
                   "at bound"), rows(table_rows))
    tables = {"currents": table}
    if data.fit is not None and math.isfinite(data.fit.intercept_j):
        error = data.fit.error
        tables["fit summary"] = Table(
            ("runs", "intercept J", "error before %", "error after %", "leave-one-out error %", "status"),
            ((data.fit.n_runs, data.fit.intercept_j, error.before * 100, error.after * 100, error.loo * 100,
              data.fit.status),))
    return ReportFigure("fig2-currents", title, how, fig, tables, tuple(missing))


def components_figure(data: ReportData) -> ReportFigure:
    """Figure 5: the calibrated model's energy by component per kernel (per second of run)."""
    plt = pyplot()
    title = "Energy by component per kernel (calibrated model)"
    how = ("Each bar is one run per kernel (its latest at its most threads) split into the DRAM model's "
           "components, per second of run so kernels with different run lengths compare.")
    if data.spec is None or data.fit is None or not data.runs:
        reason = "no calibration yet" if data.fit is None else ("the memspec is unknown" if data.spec is None
                                                                  else "no finished runs")
        return ReportFigure("fig5-components", title, how, message_figure(title, reason), missing=(reason,))
    fig, ax = plt.subplots(figsize=(8.5, 4.4))
    chosen = analysis.representative_runs(data.runs)
    energies = [analysis.component_energies(data.spec, data.fit, run) for run in chosen]
    parts = [p for p in (*analysis.COMPONENT_GROUPS, "offset") if any(abs(e[p]) > 0 for e in energies)]
    x = np.arange(len(chosen))
    bottom = np.zeros(len(chosen))
    for k, part in enumerate(parts):
        power = np.array([e[part] / run.window_s for e, run in zip(energies, chosen)])
        s = style(k)
        label = "fit intercept" if part == "offset" else part
        ax.bar(x, power, 0.6, bottom=bottom, color=s.color, hatch=s.hatch, edgecolor="#333333", linewidth=0.4,
               label=label)
        bottom += power
    ax.set_xticks(x, [run.label for run in chosen], rotation=30, ha="right")
    ax.set_ylabel("energy per second of run (J/s = W)")
    ax.set_title(title)
    legend_outside(ax)
    fig.tight_layout()
    # the components re-model each run; where that disagrees with the daemon's own row, say by how much
    gaps = [abs(sum(e.values()) - run.calibrated_j) / run.calibrated_j for e, run in zip(energies, chosen)
            if math.isfinite(run.calibrated_j) and run.calibrated_j > 0]
    notes: tuple[str, ...] = ()
    if gaps and max(gaps) > 1e-3:
        notes = (f"the split re-models the runs, which differs from the daemon's calibration rows by up to "
                 f"{max(gaps) * 100:.2g} % (another node topology or memspec than this report assumes)",)
    table = Table(("run", "kernel", "threads", "window s", *[f"{p} J" for p in parts], "sum J", "calibrated model J",
                   "measured J"),
                  rows([(run.run_id, run.kernel, run.threads or None, run.window_s, *[e[p] for p in parts],
                         float(sum(e[p] for p in parts)), run.calibrated_j, run.measured_j)
                        for run, e in zip(chosen, energies)]))
    return ReportFigure("fig5-components", title, how, fig, {"energy by component": table}, notes=notes)


def calibrated_memspec(data: ReportData) -> dict[str, Any] | None:
    """The memspec with the latest fit's currents (DRAMPower JSON), None without spec or fit."""
    if data.spec is None or data.fit is None:
        return None
    currents = data.fit.calibrated_a
    return dict(data.spec.with_currents({n: v for n, v in currents.items() if math.isfinite(v)}).to_json_dict())
