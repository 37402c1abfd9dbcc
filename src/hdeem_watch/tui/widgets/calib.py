"""The calibration panel: datasheet vs calibrated currents, intervals, identifiability, errors,
the history of each current (aging), the daemon's suggestion for the next run, and the simulator's hidden truth
(marked "simulation"): the *effective* truth a fit can recover (incl. the I/O energy per burst and
the sensor offsets) in the ``sim`` column, the core truth in ``core`` when the panel is wide enough."""

from __future__ import annotations

import math

from rich.text import Text

from hdeem_watch.tui.braille import sparkline
from hdeem_watch.tui.snapshot import CalibView
from hdeem_watch.tui.widgets.fmt import fixed
from hdeem_watch.tui.widgets.lines import LinesWidget


def _ma(value_a: float, width: int) -> str:
    return fixed(value_a * 1000.0, width, 1)


def calib_text(calib: CalibView, width: int) -> Text:
    """The panel's lines (currents in mA)."""
    text = Text(no_wrap=True, overflow="ellipsis")
    title = f"calibration ({calib.n_runs} run{'' if calib.n_runs == 1 else 's'})" if calib.n_runs else "calibration"
    text.append(title, style="bold")
    if calib.simulated:
        effective = any(math.isfinite(_core(c)) for c in calib.currents)
        if effective:
            text.append("  sim: sim truth (incl. I/O)" if width >= 50 else "  sim=simulation", style="dim italic")
        else:
            text.append("  sim: simulation truth" if width >= 44 else "  sim=simulation", style="dim italic")
    if not calib.currents:
        text.append("\n(no fit yet: waiting for runs)", style="dim italic")
        if calib.model_error:
            text.append(f"\nmodel: {calib.model_error}", style="yellow")
        return text
    show_truth = calib.simulated
    show_core = show_truth and width >= 6 + 7 + 7 + 6 + 3 + 7 + 7 + 8 and any(
        math.isfinite(_core(c)) for c in calib.currents)
    spark_width = max(0, width - (6 + 7 + 7 + 6 + 3 + (7 if show_truth else 0) + (7 if show_core else 0)) - 1)
    text.append("\n")
    header = "mA     datash  calib.  ±ci95 id" + ("    sim" if show_truth else "") + ("   core" if show_core else "")
    if spark_width >= 4:
        header += " history"
    text.append(header[:width], style="bold underline")
    for c in calib.currents:
        text.append("\n")
        text.append(f"{c.name:<6.6}", style="bold")
        text.append(_ma(c.datasheet_a, 7), style="dim")
        ratio = c.calibrated_a / c.datasheet_a if c.datasheet_a else math.nan
        text.append(_ma(c.calibrated_a, 7), style="bold green" if ratio < 0.95 else "bold")
        text.append(_ma(c.ci95_a, 7) if math.isfinite(c.ci95_a) else "      –")
        text.append(" ✓ " if c.identifiable else " ? ", style="green" if c.identifiable else "yellow")
        if show_truth:
            text.append(_ma(c.truth_a, 7), style="italic")
        if show_core:
            text.append(_ma(_core(c), 7), style="dim italic")
        if spark_width >= 4 and c.history_a:
            text.append(" " + sparkline(c.history_a[-(spark_width - 1) :]), style="cyan")
    text.append("\n")
    text.append("error ", style="bold")
    if calib.determined:
        text.append(f"before {_pct(calib.error_before)} after {_pct(calib.error_after)} loo {_pct(calib.error_loo)}")
    else:  # an exact fit through every run: "after 0 %" and the leave-one-out would mean nothing
        errors = f"before {_pct(calib.error_before)} after – loo –"
        text.append(errors)
        if len("error ") + len(errors) + 18 <= width:
            text.append("  (runs < unknowns)", style="dim italic")
    if calib.suggested_next:
        text.append("\nsuggested run: ", style="bold")
        text.append(calib.suggested_next)
    if calib.model_error:
        text.append(f"\nmodel: {calib.model_error}", style="yellow")
    return text


def _core(current: object) -> float:
    """The sim's core truth of a current (NaN when the view has none)."""
    value = getattr(current, "truth_core_a", math.nan)
    return float(value) if isinstance(value, float) else math.nan


def _pct(value: float) -> str:
    if not math.isfinite(value):
        return "–"
    return f"{value * 100:.0f}%" if abs(value) >= 0.995 else f"{value * 100:.1f}%"


class CalibPanel(LinesWidget):
    """Calibration state of the focused node."""

    def show(self, calib: CalibView) -> None:
        """Paint the panel."""
        if self.already_showing(calib):
            return
        self.set_text(calib_text(calib, self.size.width or 40))
