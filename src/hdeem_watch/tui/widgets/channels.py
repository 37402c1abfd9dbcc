"""The channel table: current value, idle baseline ± spread, power above baseline, status; with
memory counters (and room), each DRAM channel's command rates: ACT/s, RD/s, WR/s and the power-down share.

``above`` is "–" for a channel whose baseline is not its true idle (a CPU or blade channel
measured during an idle run, whose kernel keeps the CPUs busy); that baseline is dimmed.
"""

from __future__ import annotations

import math

from rich.text import Text

from hdeem_watch.tui.snapshot import NodeSnapshot
from hdeem_watch.tui.widgets.fmt import fixed, per_second
from hdeem_watch.tui.widgets.lines import LinesWidget

KIND_STYLE = {"dram": "bold cyan", "cpu": "bold magenta", "blade": "bold yellow", "other": "bold"}


def channel_table_text(snapshot: NodeSnapshot, width: int) -> Text:
    """Header plus one line per channel."""
    text = Text(no_wrap=True, overflow="ellipsis")
    wide = width >= 48
    commands = width >= 76 and any(ch.commands is not None for ch in snapshot.channels)
    text.append("channel    now W  baseline±spr  above" + ("  status      " if wide and commands else "  status" if wide else "")
                + ("  ACT/s   RD/s   WR/s  pd" if commands else ""), style="bold underline")
    if not snapshot.channels:
        text.append("\n(waiting for samples)", style="dim italic")
    for ch in snapshot.channels:
        text.append("\n")
        text.append(f"{ch.name:<7.7}", style=KIND_STYLE.get(ch.kind, "bold"))
        text.append(fixed(ch.power_w, 8, 2))
        if math.isfinite(ch.baseline_w):
            base = f"{ch.baseline_w:.1f}±{ch.spread_w:.1f}" if math.isfinite(ch.spread_w) else f"{ch.baseline_w:.1f}"
        else:
            base = "–"
        idle = math.isfinite(ch.baseline_w) and ch.baseline_is_idle
        text.append(f"{base:>14.14}", style="" if idle else "dim")
        above = ch.above_w
        style = "bold green" if math.isfinite(above) and above > max(0.5, 2 * (ch.spread_w or 0)) else ""
        text.append(fixed(above, 7, 1, sign=True), style=style)
        if wide:
            status_style = "green" if ch.status == "ok" else "bold red"
            text.append(f"  {ch.status[:12]:<12}" if commands else f"  {ch.status[:12]}", style=status_style)
        if commands and ch.commands is not None:
            c = ch.commands
            text.append(per_second(c.act_per_s, 7) + per_second(c.rd_per_s, 7) + per_second(c.wr_per_s, 7), style="cyan")
            text.append(fixed(100 * c.powerdown_share, 4, 0, suffix="%"))
    return text


class ChannelTable(LinesWidget):
    """Per-channel values of the focused node."""

    def show(self, snapshot: NodeSnapshot) -> None:
        """Paint the table."""
        if self.already_showing(snapshot):
            return
        self.set_text(channel_table_text(snapshot, self.size.width or 40))
