"""Power plots: one strip per channel, a Braille min/max envelope of the time window."""

from __future__ import annotations

from rich.text import Text
from textual.widgets import Static

from hdeem_watch.tui.braille import braille_envelope
from hdeem_watch.tui.downsample import finite_range
from hdeem_watch.tui.snapshot import ChannelView, NodeSnapshot
from hdeem_watch.tui.widgets.channels import KIND_STYLE
from hdeem_watch.tui.widgets.fmt import crop, fixed

#: Characters left of each strip (channel name, value, axis).
LABEL_WIDTH = 8
_STRIP_STYLE = {"dram": "cyan", "cpu": "magenta", "blade": "yellow", "other": "white"}


def strip_heights(n_channels: int, rows: int, kinds: list[str]) -> list[int]:
    """Rows per channel strip: at least one each, extra rows to DRAM channels first."""
    if n_channels == 0:
        return []
    heights = [1] * n_channels
    spare = max(0, rows - n_channels)
    order = [i for i, k in enumerate(kinds) if k == "dram"] + [i for i, k in enumerate(kinds) if k != "dram"]
    while spare > 0:
        for i in order:
            if spare == 0:
                break
            heights[i] += 1
            spare -= 1
    return heights


def _strip(ch: ChannelView, height: int, plot_width: int) -> list[Text]:
    columns = ch.columns
    lines = [Text(no_wrap=True) for _ in range(height)]
    lines[0].append(f"{ch.name:<{LABEL_WIDTH}.{LABEL_WIDTH - 1}}", style=KIND_STYLE.get(ch.kind, "bold"))
    if columns is None:
        for line in lines[1:]:
            line.append(" " * LABEL_WIDTH)
        for line in lines:
            line.append("·" * plot_width, style="dim")
        return lines
    bounds = finite_range(columns.min_w, columns.max_w)
    lo, hi = bounds if bounds is not None else (0.0, 1.0)
    pad = max((hi - lo) * 0.05, 0.25)
    lo, hi = lo - pad, hi + pad
    rows = braille_envelope(columns.min_w, columns.max_w, lo=lo, hi=hi, height=height)
    labels = [fixed(hi, LABEL_WIDTH - 1, 1) + " ", fixed(lo, LABEL_WIDTH - 1, 1) + " "]
    for i, line in enumerate(lines):
        if i == 0:
            pass  # the channel name is already there
        elif i == height - 1:
            line.append(labels[1], style="dim")
        elif i == 1 and height > 2:
            line.append(labels[0], style="dim")
        else:
            line.append(" " * LABEL_WIDTH)
        row = rows[i][:plot_width]
        line.append(row.ljust(plot_width, "⠀"), style=_STRIP_STYLE.get(ch.kind, "white"))
    return lines


def plots_text(snapshot: NodeSnapshot, width: int, rows: int) -> Text:
    """All strips of the focused node, filling ``rows`` lines of ``width`` characters."""
    plot_width = max(4, width - LABEL_WIDTH)
    channels = list(snapshot.channels)
    text = Text(no_wrap=True, overflow="crop")
    if not channels:
        text.append("(no samples yet)", style="dim italic")
        return text
    heights = strip_heights(len(channels), max(rows, len(channels)), [c.kind for c in channels])
    lines: list[Text] = []
    for ch, height in zip(channels, heights):
        lines.extend(_strip(ch, height, plot_width))
    return Text("\n", no_wrap=True).join(lines[: max(rows, 1)])


class PowerPlots(Static):
    """The plot area; its width decides how many columns the feed downsamples to."""

    def data_columns(self) -> int:
        """Data columns the feed should compute (two Braille dots per character)."""
        return 2 * max(4, (self.size.width or 80) - LABEL_WIDTH)

    def show(self, snapshot: NodeSnapshot) -> None:
        """Paint the strips."""
        key = (id(snapshot), self.size)
        if key == getattr(self, "_shown", None):
            return
        self._shown = key
        self.update(crop(plots_text(snapshot, self.size.width or 80, self.size.height or 14), self.size.width or 80))
