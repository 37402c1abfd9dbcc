"""The per-pair calibration view driven by Textual's pilot at 80×24 (frozen snapshots: a fit per
DIMM pair, one pair with a drift alarm), and its text at the narrowest width."""

from __future__ import annotations

from hdeem_watch.tui.app import GroupsScreen, HdeemWatchApp
from hdeem_watch.tui.provider import StaticProvider
from hdeem_watch.tui.snapshot import CalibView
from hdeem_watch.tui.widgets import CalibPanel, GroupsPanel
from hdeem_watch.tui.widgets.groups import groups_text


async def test_g_opens_the_per_pair_view_and_esc_returns(frozen_snapshot) -> None:  # type: ignore[no-untyped-def]
    snap = frozen_snapshot(plot_cells=32)
    app = HdeemWatchApp(StaticProvider([snap]), fps=5, clock=lambda: snap.built_mono_ns)
    async with app.run_test(size=(80, 24)) as pilot:
        await pilot.pause()
        await pilot.press("g")
        await pilot.pause(0.3)
        assert isinstance(app.screen, GroupsScreen)
        text = app.screen.query_one(GroupsPanel).plain
        lines = text.splitlines()
        header = next(line for line in lines if "DDR_AB" in line)
        assert header.split() == ["datash", "DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH", "node"]
        idd4r = next(line for line in lines if line.startswith("idd4r")).split()
        assert idd4r[1] == "97.2"  # the datasheet, mA
        assert idd4r[2] == "96.5±2.0" and idd4r[3] == "120.6±2.0" and idd4r[6] == "102.3±2.0"  # pair fits, node fit
        drift = next(line for line in lines if line.startswith("drift")).split()
        assert drift == ["drift", "ok", "DRIFT↑", "ok", "ok", "ok"]
        assert "ALARM DDR_CD energy drifts up (residual-cusum 12.4 > 12)" in text
        assert all(len(line) <= 80 for line in lines), text
        await pilot.press("escape")
        await pilot.pause(0.2)
        assert not isinstance(app.screen, GroupsScreen)
        assert "calibration" in app.query_one(CalibPanel).plain


def test_without_groups_the_view_says_so() -> None:
    text = groups_text(CalibView(), 80).plain
    assert "no per-pair fits" in text


def test_fit_states_fit_their_column_at_80_columns() -> None:
    """A fit at a bound reads "at bound" (it was cut to "at-boun"), an underdetermined one "underdet."."""
    from hdeem_watch.tui.snapshot import CurrentView, GroupFitView

    current = (CurrentView("idd0", 0.1074, 0.028, 0.002, True),)
    groups = tuple(GroupFitView(name, current, runs=100, status=status) for name, status in
                   (("DDR_AB", "ok"), ("DDR_CD", "at-bound"), ("DDR_EF", "underdetermined"), ("DDR_GH", "ok"),
                    ("node", "rank-deficient")))
    lines = groups_text(CalibView(groups=groups), 80).plain.splitlines()
    drift = next(line for line in lines if line.startswith("drift"))
    assert drift.split() == ["drift", "ok", "at", "bound", "underdet.", "ok", "rank-def."]
    assert all(len(line) <= 80 for line in lines)
