"""The held-out figure: workloads the calibration never fitted, measured vs datasheet vs calibrated.

Hold-out runs (kernels of :data:`hdeem_watch.dram.kernels.HOLDOUT_KERNELS`: GUPS-like random reads,
a pointer chase, 2-/4-line strides, a 3:1 read/write mix; announced with ``metadata.holdout`` and
never fitted) are predicted with the fit from *before* each run (``predicted_j``), so the figure
shows how the calibration carries to what it never saw — the paper's key figure.
"""

from __future__ import annotations

from hdeem_watch.report import analysis
from hdeem_watch.report.figure import ReportFigure
from hdeem_watch.report.figures_model import measured_vs_models
from hdeem_watch.report.records import ReportData
from hdeem_watch.report.style import message_figure

KEY = "fig7-holdout"
TITLE = "Held-out workloads: measured, datasheet model, calibrated model (fit from before each run)"


def holdout_figure(data: ReportData) -> ReportFigure:
    """Figure 7: per hold-out kernel and thread count the mean measured energy beside both models'."""
    groups = analysis.holdout_groups(data.runs)
    how = ("Runs of kernels the calibration never fitted, each predicted with the fit from before it; the lower "
           "panel is each model's error against the measurement (0 % = exact).")
    if not groups:  # one clear panel, not two empty boxes
        fig = message_figure(TITLE, "no hold-out runs: kernels the fit never saw, predicted from before each run\n"
                                    "(hdeem-watch demo runs them; so does hdeem-watch bench --kernels holdout --daemon)")
        return ReportFigure(KEY, TITLE, how, fig, missing=("hold-out runs",))
    fig, table = measured_vs_models(groups, "Held-out workloads (never fitted)")
    return ReportFigure(KEY, TITLE, how, fig, {"mean energy per hold-out kernel and thread count": table})
