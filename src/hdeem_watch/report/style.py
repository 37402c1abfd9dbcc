"""How report figures look: matplotlib (Agg, imported only here and only when a report is drawn),
the Okabe–Ito palette with a marker and a hatch per series (readable in grey-scale and for
colour-blind readers), and the panel that says a figure has no data.

Example::

    plt = pyplot()               # raises MissingPlotting without matplotlib
    fig, ax = plt.subplots()
    style = SERIES["measured"]   # colour, marker, hatch
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

#: Okabe & Ito (2008), "Color Universal Design": distinguishable for every common colour-vision type.
OKABE_ITO = ("#E69F00", "#56B4E9", "#009E73", "#F0E442", "#0072B2", "#D55E00", "#CC79A7", "#000000")


@dataclass(frozen=True)
class SeriesStyle:
    """Colour, marker and hatch of one series (the marker and hatch carry it without colour)."""

    color: str
    marker: str
    hatch: str


#: The three energies of figure 1 and the two currents of figure 2: grey levels differ too.
SERIES = {
    "measured": SeriesStyle("#000000", "o", ""),
    "datasheet": SeriesStyle("#E69F00", "s", "//"),
    "calibrated": SeriesStyle("#0072B2", "^", ".."),
}
#: Per series of a multi-series figure (currents, channels, components, kernels), in order.
CYCLE = tuple(SeriesStyle(color, marker, hatch) for color, marker, hatch in zip(
    ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#000000", "#F0E442"),
    ("o", "s", "^", "D", "v", "P", "X", "*"),
    ("", "//", "..", "xx", "\\\\", "oo", "--", "++")))


class MissingPlotting(RuntimeError):
    """matplotlib is not installed (the ``report`` extra)."""


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend, with the report's defaults.

    Raises:
        MissingPlotting: matplotlib is not installed.
    """
    try:
        import matplotlib
    except ImportError:
        raise MissingPlotting("install hdeem-watch[report] (matplotlib) to draw reports") from None
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    plt.rcParams.update({
        "figure.dpi": 100, "savefig.dpi": 110, "font.size": 9, "axes.titlesize": 10,
        "axes.grid": True, "grid.alpha": 0.3, "axes.spines.top": False, "axes.spines.right": False,
        "legend.fontsize": 8, "legend.frameon": False, "svg.fonttype": "none", "svg.hashsalt": "hdeem-watch",
        "hatch.linewidth": 0.6,
    })
    return plt


def style(index: int) -> SeriesStyle:
    """The style of the ``index``-th series (cycling)."""
    return CYCLE[index % len(CYCLE)]


def no_data(ax: Any, message: str) -> None:
    """Turn ``ax`` into a panel that says, in words, why there is nothing to plot."""
    ax.set_axis_off()
    ax.text(0.5, 0.5, message, ha="center", va="center", wrap=True, fontsize=10, transform=ax.transAxes,
            bbox={"boxstyle": "round", "facecolor": "#f2f2f2", "edgecolor": "#999999"})


def message_figure(title: str, message: str) -> Any:
    """A figure that is one short panel saying why there is nothing to draw (never an empty box)."""
    fig, ax = pyplot().subplots(figsize=(8.5, 1.8))
    no_data(ax, message)
    ax.set_title(title)
    fig.tight_layout()
    return fig


def percent_axis(ax: Any, label: str) -> None:
    """A symmetric-log percent axis (linear within ±1 %) labelled with plain numbers."""
    from matplotlib.ticker import FuncFormatter

    ax.set_yscale("symlog", linthresh=1.0)
    ax.yaxis.set_major_formatter(FuncFormatter(lambda value, _pos: f"{value:g}"))
    ax.set_ylabel(label)


def legend_outside(ax: Any) -> None:
    """The legend to the right of the axes, so it never hides data."""
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0))
