"""Power plots: one strip per channel, a Braille min/max envelope of the time window.

Left of each strip: the channel's name and the strip's vertical range in W (``lo–hi`` under the
name in a two-row strip; the top on the second row and the bottom on the last in a taller one).
"""

from __future__ import annotations

from hdeem_watch.tui.braille import braille_envelope
from hdeem_watch.tui.downsample import finite_range
from hdeem_watch.tui.snapshot import ChannelView, NodeSnapshot
from hdeem_watch.tui.widgets.channels import KIND_STYLE
from hdeem_watch.tui.widgets.fmt import fixed
from hdeem_watch.tui.widgets.lines import LinesWidget, Run

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


def range_label(lo: float, hi: float, width: int) -> str:
    """A strip's vertical range in at most ``width`` characters, e.g. ``1.1–2.3`` or ``66–185``.

    >>> range_label(1.12, 2.34, 7), range_label(65.7, 185.2, 7), range_label(1234.0, 56789.0, 7)
    ('1.1–2.3', '66–185', '1e+03–6e+04')
    """
    for decimals in (1, 0):
        text = f"{lo:.{decimals}f}–{hi:.{decimals}f}"
        if len(text) <= width:
            return text
    return f"{lo:.0e}–{hi:.0e}"


def _strip(ch: ChannelView, height: int, plot_width: int) -> list[list[Run]]:
    columns = ch.columns
    name = (f"{ch.name:<{LABEL_WIDTH}.{LABEL_WIDTH - 1}}", KIND_STYLE.get(ch.kind, "bold"))
    blank = (" " * LABEL_WIDTH, "")
    if columns is None:
        return [[name if i == 0 else blank, ("·" * plot_width, "dim")] for i in range(height)]
    bounds = finite_range(columns.min_w, columns.max_w)
    lo, hi = bounds if bounds is not None else (0.0, 1.0)
    pad = max((hi - lo) * 0.05, 0.25)
    lo, hi = lo - pad, hi + pad
    rows = braille_envelope(columns.min_w, columns.max_w, lo=lo, hi=hi, height=height)
    style = _STRIP_STYLE.get(ch.kind, "white")
    lines: list[list[Run]] = []
    for i in range(height):
        if i == 0:
            label = name
        elif height == 2:  # one row for the label: the range as "lo–hi"
            label = (range_label(lo, hi, LABEL_WIDTH - 1).rjust(LABEL_WIDTH - 1) + " ", "dim")
        elif i == height - 1:
            label = (fixed(lo, LABEL_WIDTH - 1, 1) + " ", "dim")
        elif i == 1:
            label = (fixed(hi, LABEL_WIDTH - 1, 1) + " ", "dim")
        else:
            label = blank
        lines.append([label, (rows[i][:plot_width].ljust(plot_width, "⠀"), style)])
    return lines


def plot_lines(snapshot: NodeSnapshot, width: int, rows: int) -> list[list[Run]]:
    """All strips of the focused node as ``(text, style)`` runs, at most ``rows`` lines."""
    plot_width = max(4, width - LABEL_WIDTH)
    channels = list(snapshot.channels)
    if not channels:
        return [[("(no samples yet)", "dim italic")]]
    heights = strip_heights(len(channels), max(rows, len(channels)), [c.kind for c in channels])
    lines: list[list[Run]] = []
    for ch, height in zip(channels, heights):
        lines.extend(_strip(ch, height, plot_width))
    return lines[: max(rows, 1)]


class PowerPlots(LinesWidget):
    """The plot area; its width decides how many columns the feed downsamples to."""

    DEFAULT_CSS = "PowerPlots { height: 1fr; }"

    def data_columns(self) -> int:
        """Data columns the feed should compute (two Braille dots per character)."""
        return 2 * max(4, (self.size.width or 80) - LABEL_WIDTH)

    def show(self, snapshot: NodeSnapshot) -> None:
        """Paint the strips."""
        if self.already_showing(snapshot):
            return
        self.set_runs(plot_lines(snapshot, self.size.width or 80, self.size.height or 14))
