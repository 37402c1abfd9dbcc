"""The app's paint loop against a provider whose snapshots are replaced between paints (no daemon)."""

from __future__ import annotations

import math
from typing import Any

from hdeem_watch.tui.app import HdeemWatchApp
from hdeem_watch.tui.snapshot import ChannelView, NodeSnapshot
from hdeem_watch.tui.widgets import ChannelTable


class ReplacingProvider:
    """Holds only the newest snapshot: the previous one is freed when a new one is set, as in the
    live feed (so CPython may give the new snapshot the freed one's address, i.e. its ``id``)."""

    def __init__(self) -> None:
        self.latest = _snapshot(0)

    def start(self) -> None:
        """Nothing to start."""

    def stop(self) -> None:
        """Nothing to stop."""

    def snapshots(self) -> list[NodeSnapshot]:
        return [self.latest]

    def set_view(self, *, focus: int, window_s: float, width: int) -> None:
        """The view does not matter here."""

    def request(self, index: int, op: str, args: dict[str, Any] | None = None) -> None:
        """No requests here."""


def _snapshot(i: int) -> NodeSnapshot:
    channel = ChannelView(name="DDR_AB", kind="dram", rate_hz=100.0, power_w=float(i), baseline_w=math.nan,
                          spread_w=math.nan, baseline_origin="", energy_j=math.nan, status="ok", source_gaps=0)
    return NodeSnapshot(node="n1", built_mono_ns=i + 1, window_s=60.0, channels=(channel,))


async def test_every_new_snapshot_is_painted_even_when_its_id_is_reused() -> None:
    """Each paint shows the newest snapshot. (Keyed on ``id(snapshot)``, a new snapshot that got the
    address of the painted one, freed meanwhile, was skipped: 997 of 1000 paints in a probe.)"""
    provider = ReplacingProvider()
    app = HdeemWatchApp(provider, fps=0.2, clock=lambda: 1)
    async with app.run_test(size=(80, 24)):
        skipped = 0
        for i in range(1, 200):
            provider.latest = _snapshot(-i)  # two snapshots built between paints, as a busy feed does
            provider.latest = _snapshot(i)
            app.paint()
            values = [line.split()[1] for line in app.query_one(ChannelTable).plain.splitlines()[1:]]
            skipped += values != [f"{i:.2f}"]
        assert skipped == 0


async def test_a_paint_during_shutdown_does_nothing() -> None:
    """The paint interval can fire once more while the app shuts down, after its widgets are gone
    (CI saw ``NoMatches: PowerPlots`` from the timer at exit). Such a paint returns quietly."""
    provider = ReplacingProvider()
    app = HdeemWatchApp(provider, fps=0.2, clock=lambda: 1)
    async with app.run_test(size=(80, 24)):
        app.paint()
        painted = app.frames
    app.paint()  # the app has shut down: no widgets to query
    assert app.frames == painted
