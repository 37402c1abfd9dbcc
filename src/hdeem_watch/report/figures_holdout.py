"""The held-out figure: workloads the calibration never fitted, measured vs datasheet vs calibrated.

Hold-out runs (kernels of :data:`hdeem_watch.dram.kernels.HOLDOUT_KERNELS`: GUPS-like random reads,
a pointer chase, 2-/4-line strides, a 3:1 read/write mix; announced with ``metadata.holdout`` and
never fitted) are predicted with the fit from *before* each run (``predicted_j``), so the figure
shows how the calibration carries to what it never saw — the paper's key figure.
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass

import numpy as np

from hdeem_watch.dram.kernels import HOLDOUT_KERNELS
from hdeem_watch.report.figure import ReportFigure, Table, rows
from hdeem_watch.report.records import ReportData, RunRow
from hdeem_watch.report.style import SERIES, legend_outside, message_figure, percent_axis, pyplot

KEY = "fig7-holdout"
TITLE = "Held-out workloads: measured, datasheet model, calibrated model (fit from before each run)"


@dataclass(frozen=True)
class HoldoutGroup:
    """The hold-out runs of one kernel at one thread count (mean energies, J; errors in %)."""

    kernel: str
    threads: int
    n: int
    measured_j: float
    datasheet_j: float
    calibrated_j: float

    @property
    def datasheet_error_pct(self) -> float:
        return 100.0 * (self.datasheet_j / self.measured_j - 1.0)

    @property
    def calibrated_error_pct(self) -> float:
        return 100.0 * (self.calibrated_j / self.measured_j - 1.0)


def holdout_groups(runs: tuple[RunRow, ...] | list[RunRow]) -> list[HoldoutGroup]:
    """Hold-out runs with a measurement and a prediction, grouped by kernel and thread count."""
    chosen: dict[tuple[str, int], list[RunRow]] = {}
    for run in runs:
        if run.kernel in HOLDOUT_KERNELS and run.measured_j > 0 and math.isfinite(run.predicted_j) \
                and math.isfinite(run.datasheet_j):
            chosen.setdefault((run.kernel, run.threads), []).append(run)
    order = {k: i for i, k in enumerate(HOLDOUT_KERNELS)}
    return [HoldoutGroup(kernel, threads, len(group), statistics.fmean(r.measured_j for r in group),
                         statistics.fmean(r.datasheet_j for r in group), statistics.fmean(r.predicted_j for r in group))
            for (kernel, threads), group in sorted(chosen.items(), key=lambda kv: (order[kv[0][0]], kv[0][1]))]


def holdout_figure(data: ReportData) -> ReportFigure:
    """Figure 7: per hold-out kernel and thread count the mean measured energy beside both models'."""
    plt = pyplot()
    groups = holdout_groups(data.runs)
    how = ("Runs of kernels the calibration never fitted, each predicted with the fit from before it; the lower "
           "panel is each model's error against the measurement (0 % = exact).")
    if not groups:  # one clear panel, not two empty boxes
        fig = message_figure(TITLE, "no hold-out runs: kernels the fit never saw, predicted from before each run\n"
                                    "(hdeem-watch demo runs them; so does hdeem-watch bench --kernels holdout --daemon)")
        return ReportFigure(KEY, TITLE, how, fig, missing=("hold-out runs",))
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(max(7.0, 0.5 * len(groups) + 2), 6.0), sharex=True,
                                      gridspec_kw={"height_ratios": (3, 2)})
    x = np.arange(len(groups))
    width = 0.27
    for k, (name, values) in enumerate((("measured", [g.measured_j for g in groups]),
                                       ("datasheet", [g.datasheet_j for g in groups]),
                                       ("calibrated", [g.calibrated_j for g in groups]))):
        s = SERIES[name]
        top.bar(x + (k - 1) * width, values, width, label=name + (" model" if k else ""), color=s.color,
                hatch=s.hatch, edgecolor="white" if k == 0 else "#333333", linewidth=0.4)
    top.set_ylabel("DRAM energy per run (J)")
    top.set_title("Held-out workloads (never fitted)")
    legend_outside(top)
    for name, values in (("datasheet", [g.datasheet_error_pct for g in groups]),
                         ("calibrated", [g.calibrated_error_pct for g in groups])):
        s = SERIES[name]
        bottom.plot(x, values, linestyle="none", marker=s.marker, color=s.color, label=f"{name} model",
                    markersize=6, markeredgecolor="#333333", markeredgewidth=0.5)
    bottom.axhline(0.0, color="#333333", linewidth=0.8)
    percent_axis(bottom, "error vs measured (%)")
    errors = [v for g in groups for v in (g.datasheet_error_pct, g.calibrated_error_pct)]
    bottom.set_ylim(min(-2.0, 2.0 * min(errors)), max(2.0, 2.0 * max(errors)))
    legend_outside(bottom)
    bottom.set_xticks(x, [f"{g.kernel}-{g.threads}t" + (f" ×{g.n}" if g.n > 1 else "") for g in groups],
                      rotation=60, ha="right")
    fig.tight_layout()
    table = Table(("kernel", "threads", "runs", "measured J", "datasheet J", "calibrated J", "datasheet error %",
                   "calibrated error %"),
                  rows([(g.kernel, g.threads or None, g.n, g.measured_j, g.datasheet_j, g.calibrated_j,
                         g.datasheet_error_pct, g.calibrated_error_pct) for g in groups]))
    return ReportFigure(KEY, TITLE, how, fig, {"mean energy per hold-out kernel and thread count": table})
