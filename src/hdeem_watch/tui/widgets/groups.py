"""The per-pair calibration view: each sensor group's fitted currents (with their 95 % intervals)
beside the datasheet and the node fit, its runs and leave-one-out error, and a drift badge (the
group's newest alarm). Fits 80 columns with four pairs; wider terminals get wider columns."""

from __future__ import annotations

import math

from rich.text import Text

from hdeem_watch.tui.group_views import alarm_text
from hdeem_watch.tui.snapshot import CalibView, GroupFitView
from hdeem_watch.tui.widgets.fmt import percent
from hdeem_watch.tui.widgets.lines import LinesWidget

#: Width of the current-name column and of the datasheet column.
NAME_W, DATASHEET_W = 6, 7
#: Narrowest column of one group ("123.4±12" and a space).
MIN_GROUP_W = 9


def _value(value_a: float, ci_a: float, width: int) -> str:
    """``mA±ci`` right-aligned in ``width`` (the interval dropped when it does not fit; – when unknown)."""
    if not math.isfinite(value_a):
        return "–".rjust(width)
    main = f"{value_a * 1000:.1f}"
    if math.isfinite(ci_a):
        ci_ma = ci_a * 1000
        with_ci = f"{main}±{ci_ma:.1f}" if ci_ma < 10 else f"{main}±{ci_ma:.0f}"
        if len(with_ci) < width:
            return with_ci.rjust(width)
    return main.rjust(width)


#: The fit states as they fit a column (the view is 80 columns wide for four pairs and the node).
STATUS_LABELS = {"at-bound": "at bound", "underdetermined": "underdet.", "rank-deficient": "rank-def."}


def _badge(group: GroupFitView) -> tuple[str, str]:
    """The drift badge: ``DRIFT↑``/``DRIFT↓`` for the newest alarm (its energy drifts against its fit, or
    a current changed since its own reference fit more than its siblings': both are changes over
    time; the alarm lines below say which), else the fit's state."""
    if group.alarms:
        alarm = group.alarms[-1]
        arrow = "↑" if alarm.direction == "up" else "↓"
        return "DRIFT" + arrow, "bold white on red"
    if not group.status:
        return "no fit", "dim"
    label = STATUS_LABELS.get(group.status, group.status)
    return label, "green" if group.status == "ok" else "yellow"


def groups_text(calib: CalibView, width: int) -> Text:
    """The view's lines: a header of groups, one line per current (mA per device), then runs, LOO
    error and the drift badge per group, then the alarms (newest last)."""
    text = Text(no_wrap=True, overflow="ellipsis")
    text.append("per-pair calibration", style="bold")
    text.append("  mA per device, fit ±95 % interval; g/esc: back", style="dim italic")
    if not calib.groups:
        text.append("\n(no per-pair fits: the daemon keeps none, or no run yet)", style="dim italic")
        return text
    groups = list(calib.groups)
    column = max(MIN_GROUP_W, (width - NAME_W - DATASHEET_W) // len(groups))
    text.append("\n")
    text.append(f"{'':<{NAME_W}}{'datash':>{DATASHEET_W}}", style="bold underline")
    for g in groups:
        text.append(f"{g.name[:column - 1]:>{column}}", style="bold underline")
    names = [c.name for c in next((g.currents for g in groups if g.currents), ())]
    datasheet = {c.name: c.datasheet_a for g in groups for c in g.currents}
    for name in names:
        text.append("\n")
        text.append(f"{name:<{NAME_W}.{NAME_W}}", style="bold")
        ds = datasheet.get(name, math.nan)
        text.append(f"{ds * 1000:>{DATASHEET_W}.1f}" if math.isfinite(ds) else "–".rjust(DATASHEET_W), style="dim")
        for g in groups:
            current = next((c for c in g.currents if c.name == name), None)
            if current is None:
                text.append("–".rjust(column), style="dim")
                continue
            style = "" if current.identifiable else "yellow"
            text.append(_value(current.calibrated_a, current.ci95_a, column), style=style)
    text.append("\n")
    text.append(f"{'runs':<{NAME_W + DATASHEET_W}}", style="bold")
    for g in groups:
        text.append(f"{g.runs:>{column}}")
    text.append("\n")
    text.append(f"{'loo':<{NAME_W + DATASHEET_W}}", style="bold")
    for g in groups:
        text.append(percent(g.error_loo, column))
    text.append("\n")
    text.append(f"{'drift':<{NAME_W + DATASHEET_W}}", style="bold")
    for g in groups:
        badge, style = _badge(g)
        text.append(" " * max(1, column - len(badge)))
        text.append(badge[:column - 1], style=style)
    for alarm in calib.alarms[-3:]:
        text.append("\n")
        text.append("ALARM ", style="bold red")
        text.append(alarm_text(alarm))
    return text


class GroupsPanel(LinesWidget):
    """The per-pair calibration view."""

    def show(self, calib: CalibView) -> None:
        """Repaint from ``calib``."""
        if self.already_showing(calib):
            return
        self.set_text(groups_text(calib, self.size.width or 80))
