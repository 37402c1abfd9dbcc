"""Where the app gets its snapshots: a :class:`Provider` protocol and a static implementation.

The live provider is :class:`hdeem_watch.tui.feed.FeedHub` (one subscriber thread per daemon);
:class:`StaticProvider` serves fixed snapshots (snapshot tests, screenshots) and records the
control requests it is asked to send.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

from hdeem_watch.tui.snapshot import NodeSnapshot


class Provider(Protocol):
    """What :class:`hdeem_watch.tui.app.HdeemWatchApp` needs from its data source."""

    def start(self) -> None:
        """Begin producing snapshots."""

    def stop(self) -> None:
        """Stop and release sockets/threads."""

    def snapshots(self) -> list[NodeSnapshot]:
        """The newest snapshot of every node (same length and order every call)."""
        ...

    def set_view(self, *, focus: int, window_s: float, width: int) -> None:
        """What the app shows: focused node, time window, plot data columns."""

    def request(self, index: int, op: str, args: dict[str, Any] | None = None) -> None:
        """Send a control request to daemon ``index`` (asynchronously)."""


class StaticProvider:
    """Fixed snapshots.

    Args:
        snapshots: one per node.
    """

    def __init__(self, snapshots: Sequence[NodeSnapshot]) -> None:
        self._snapshots = list(snapshots)
        self.requests: list[tuple[int, str, dict[str, Any]]] = []
        self.view: tuple[int, float, int] = (0, 60.0, 0)

    def start(self) -> None:
        """Nothing to start."""

    def stop(self) -> None:
        """Nothing to stop."""

    def snapshots(self) -> list[NodeSnapshot]:
        """The fixed snapshots."""
        return list(self._snapshots)

    def set_view(self, *, focus: int, window_s: float, width: int) -> None:
        """Remember the view (tests read it)."""
        self.view = (focus, window_s, width)

    def request(self, index: int, op: str, args: dict[str, Any] | None = None) -> None:
        """Record the request."""
        self.requests.append((index, op, dict(args or {})))
