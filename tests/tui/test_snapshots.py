"""Screenshots of the app from frozen snapshots (no live data), compared with pytest-textual-snapshot."""

from __future__ import annotations

from hdeem_watch.tui.app import HdeemWatchApp
from hdeem_watch.tui.provider import StaticProvider


def frozen_app(build, *, nodes: int = 1, stale: bool = False, columns: int = 80) -> HdeemWatchApp:  # type: ignore[no-untyped-def]
    plot_cells = columns // 2 - 8  # the plot area of the left half
    snaps = [build(f"taurusi600{i + 1}", stale=stale and i == 0, plot_cells=plot_cells) for i in range(nodes)]
    return HdeemWatchApp(StaticProvider(snaps), fps=2, clock=lambda: snaps[0].built_mono_ns)


async def painted(pilot) -> None:  # type: ignore[no-untyped-def]
    """Paint a frame before the keys and the screenshot: the app's first paint comes after its
    first refresh, which a loaded machine may not have reached when the screenshot is taken."""
    await pilot.pause()
    pilot.app.paint()
    await pilot.pause()


def test_snapshot_80x24(snap_compare, frozen_snapshot) -> None:  # type: ignore[no-untyped-def]
    """At 80×24 every panel is readable: channels, plots, calibration, runs, health and keys."""
    assert snap_compare(frozen_app(frozen_snapshot), terminal_size=(80, 24), run_before=painted)


def test_snapshot_100x30_two_nodes(snap_compare, frozen_snapshot) -> None:  # type: ignore[no-untyped-def]
    """At 100×30 with two nodes the health bar shows the node dots and n selects the second node."""
    assert snap_compare(frozen_app(frozen_snapshot, nodes=2, columns=100), terminal_size=(100, 30), press=["n"], run_before=painted)


def test_snapshot_stale(snap_compare, frozen_snapshot) -> None:  # type: ignore[no-untyped-def]
    """A node silent for 10 s says STALE with its age (never a frozen screen that looks live)."""
    assert snap_compare(frozen_app(frozen_snapshot, stale=True), terminal_size=(80, 24), run_before=painted)


def test_snapshot_paused_help(snap_compare, frozen_snapshot) -> None:  # type: ignore[no-untyped-def]
    """p says PAUSED in the health bar; ? opens the key help over the dashboard."""
    assert snap_compare(frozen_app(frozen_snapshot), terminal_size=(80, 24), press=["p", "question_mark"],
                       run_before=painted)


def test_snapshot_per_pair_view_80x24(snap_compare, frozen_snapshot) -> None:  # type: ignore[no-untyped-def]
    """g opens the per-pair calibration view: each pair's currents ±95 % beside the datasheet and the
    node fit, runs, LOO error and a drift badge (DDR_CD drifts up)."""
    assert snap_compare(frozen_app(frozen_snapshot), terminal_size=(80, 24), press=["g"], run_before=painted)
