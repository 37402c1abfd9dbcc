"""The connection/health bar: state, staleness, gaps, source health, the daemon's overhead.

It is the UI's promise never to show a frozen screen that looks live: a node without messages for
a few seconds turns ``STALE``, an unreachable daemon ``RECONNECTING``, a feed that stopped
producing snapshots ``UI STALLED``, and pause says ``PAUSED``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from rich.text import Text

from hdeem_watch.tui.snapshot import NodeSnapshot
from hdeem_watch.tui.widgets.fmt import megabytes
from hdeem_watch.tui.widgets.lines import LinesWidget

_STATE_STYLE = {
    "live": "bold black on green",
    "stale": "bold white on red",
    "reconnecting": "bold white on red",
    "connecting": "bold black on yellow",
    "paused": "bold black on yellow",
    "stalled": "bold white on red",
}
_DOT_STYLE = {"live": "green", "connecting": "yellow"}


def state_label(snapshot: NodeSnapshot, *, paused: bool, stalled: bool) -> tuple[str, str]:
    """The state word and its style for one node."""
    health = snapshot.health
    if stalled:
        return "UI STALLED", _STATE_STYLE["stalled"]
    if paused:
        return "PAUSED", _STATE_STYLE["paused"]
    word = health.state.upper()
    if health.state == "stale" and math.isfinite(health.last_rx_age_s):
        word = f"STALE {health.last_rx_age_s:.0f}s"
    return word, _STATE_STYLE.get(health.state, "bold")


def short_endpoint(endpoint: str, width: int = 28) -> str:
    """An endpoint cut in the middle to ``width`` characters (the end of an ipc path says the most).

    >>> short_endpoint("ipc:///tmp/hdeem-watch-demo-abc123/control.sock", 24)
    'ipc://…c123/control.sock'
    """
    if len(endpoint) <= width:
        return endpoint
    scheme, sep, rest = endpoint.partition("://")
    head = scheme + sep
    return head + "…" + rest[-(width - len(head) - 1) :]


def health_text(
    snapshots: Sequence[NodeSnapshot],
    focus: int,
    *,
    paused: bool,
    stalled: bool,
    window_s: float,
    width: int,
) -> Text:
    """The bar's text for the focused node (plus one dot per node when there are several).

    While the node is not live, the reason comes right after its name, before the figures that
    mean little then, so a narrow terminal still shows why.
    """
    snap = snapshots[focus]
    health = snap.health
    word, style = state_label(snap, paused=paused, stalled=stalled)
    text = Text(no_wrap=True, overflow="ellipsis")
    text.append(f" {word} ", style=style)
    text.append(f" {snap.node if snap.node != '?' else short_endpoint(health.endpoint)}", style="bold")
    if len(snapshots) > 1:
        text.append(f" {focus + 1}/{len(snapshots)} ")
        for i, other in enumerate(snapshots):
            dot_style = _DOT_STYLE.get(other.health.state, "red")
            text.append("●" if i == focus else "•", style=dot_style)
    detail = health.detail if health.state != "live" or health.detail.startswith("bad message") else ""
    if detail.startswith("no daemon socket"):
        detail = "no daemon socket"  # at the endpoint's path, shown already
    if detail:
        text.append("  " + detail, style="italic")
    source = health.source_kind or "?"
    if health.source_health:
        source += f":{health.source_health}"
    src_style = "green" if health.source_health in ("ok", "") else "bold red"
    text.append("  src ", style="dim")
    text.append(source[:24], style=src_style)
    text.append("  gaps ", style="dim")
    text.append(str(health.gaps), style="bold red" if health.gaps else "")
    if health.restarts:
        text.append(f"  restarts {health.restarts}", style="yellow")
    text.append("  daemon ", style="dim")
    cpu = f"{health.cpu_percent:.1f}%" if math.isfinite(health.cpu_percent) else "–"
    text.append(f"{cpu} {megabytes(health.rss_bytes)}")
    text.append(f"  win {window_s:g}s", style="dim")
    text.truncate(max(1, width), overflow="ellipsis")
    return text


class HealthBar(LinesWidget):
    """One line at the top of the screen."""

    DEFAULT_CSS = "HealthBar { height: 1; }"

    def show(
        self, snapshots: Sequence[NodeSnapshot], focus: int, *, paused: bool, stalled: bool, window_s: float
    ) -> None:
        """Paint the bar."""
        self.set_text(
            health_text(
                snapshots, focus, paused=paused, stalled=stalled, window_s=window_s, width=self.size.width or 80
            )
        )
