"""The runs panel: the run in progress and the finished runs, newest first, with measured and
modelled energy (datasheet and calibrated currents) and the model's errors."""

from __future__ import annotations

from rich.text import Text

from hdeem_watch.tui.snapshot import NodeSnapshot, RunView
from hdeem_watch.tui.widgets.fmt import duration, energy, percent
from hdeem_watch.tui.widgets.lines import LinesWidget


def _row(run: RunView, wide: bool) -> Text:
    text = Text(no_wrap=True, overflow="ellipsis")
    text.append(f"{run.kernel:<9.9}", style="bold" if run.running else "")
    text.append(f"{run.threads:>3}" if run.threads else "  –")
    text.append(f"{duration(run.duration_s):>6}")
    if run.running:
        text.append("  running…", style="bold yellow")
        return text
    text.append(energy(run.measured_j, 7))
    if wide:
        text.append(energy(run.model_datasheet_j, 8), style="dim")
        text.append(energy(run.model_calibrated_j, 8))
    text.append(percent(run.error_datasheet, 8 if wide else 6), style="red")
    text.append(percent(run.error_calibrated, 8 if wide else 6), style="green")
    return text


HEADER_NARROW = f"{'kernel':<9}{'thr':>3}{'dur':>6}{'meas J':>7}{'ds %':>6}{'cal %':>6}"
HEADER_WIDE = f"{'kernel':<9}{'thr':>3}{'dur':>6}{'meas J':>7}{'ds J':>8}{'cal J':>8}{'ds err':>8}{'cal err':>8}"


def runs_text(snapshot: NodeSnapshot, width: int, rows: int) -> Text:
    """Header, the run in progress, then finished runs newest first, cut to ``rows`` lines."""
    wide = width >= len(HEADER_WIDE)
    text = Text(no_wrap=True, overflow="ellipsis")
    header = HEADER_WIDE if wide else HEADER_NARROW
    text.append(f"runs ({max(snapshot.runs_total, len(snapshot.runs))})", style="bold")
    if any(r.simulated for r in snapshot.runs) or (snapshot.current_run and snapshot.current_run.simulated):
        text.append("  simulated node", style="dim italic")
    text.append("  (model: datasheet vs calibrated currents)" if wide else "", style="dim")
    text.append("\n")
    text.append(header, style="bold underline")
    lines: list[Text] = []
    if snapshot.current_run is not None:
        lines.append(_row(snapshot.current_run, wide))
    for run in reversed(snapshot.runs):
        lines.append(_row(run, wide))
    if not lines:
        lines.append(Text("(no runs yet)", style="dim italic"))
    for line in lines[: max(1, rows - 2)]:
        text.append("\n")
        text.append_text(line)
    return text


class RunsPanel(LinesWidget):
    """Runs of the focused node."""

    def show(self, snapshot: NodeSnapshot) -> None:
        """Paint the panel."""
        if self.already_showing(snapshot):
            return
        self.set_text(runs_text(snapshot, self.size.width or 40, self.size.height or 10))
