"""The app driven by Textual's pilot against a real daemon process (sim source)."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable

import pytest

from hdeem_watch.demo.fakenode import FakeNode
from hdeem_watch.tui.app import HdeemWatchApp
from hdeem_watch.tui.feed import FeedHub
from hdeem_watch.tui.widgets import ChannelTable, HealthBar
from hdeem_watch.wire.client import ControlClient


def shown(app: HdeemWatchApp, widget_type: type) -> str:
    """The text a widget currently shows."""
    return app.query_one(widget_type).plain


async def until(cond: Callable[[], bool], timeout_s: float = 15.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError("condition not met in time")
        await asyncio.sleep(0.1)


def dram_values(text: str) -> dict[str, str]:
    """``{channel: current value}`` from the channel table's text."""
    out = {}
    for line in text.splitlines():
        parts = line.split()
        if parts and parts[0].startswith("DDR_") and len(parts) > 1:
            out[parts[0]] = parts[1]
    return out


@pytest.mark.slow
async def test_values_update_and_pause_freezes_the_screen(sim_daemon) -> None:  # type: ignore[no-untyped-def]
    """Live DRAM values change on screen; p freezes the panels and says PAUSED; p again resumes."""
    app = HdeemWatchApp(FeedHub([sim_daemon.control_endpoint]), fps=10)
    async with app.run_test(size=(100, 30)):
        await until(lambda: "LIVE" in shown(app, HealthBar) and len(dram_values(shown(app, ChannelTable))) == 4)
        assert "pilot" in shown(app, HealthBar) and "sim" in shown(app, HealthBar)
        first = dram_values(shown(app, ChannelTable))
        await until(lambda: dram_values(shown(app, ChannelTable)) != first)
        assert all(v.replace(".", "").isdigit() for v in dram_values(shown(app, ChannelTable)).values())
        await app.run_action("pause")
        frozen = shown(app, ChannelTable)
        await asyncio.sleep(1.5)
        assert "PAUSED" in shown(app, HealthBar)
        assert shown(app, ChannelTable) == frozen
        await app.run_action("pause")
        await until(lambda: shown(app, ChannelTable) != frozen)
        assert "LIVE" in shown(app, HealthBar)


@pytest.mark.slow
async def test_keys_zoom_node_switch_and_baseline_request(sim_daemon, fake_node) -> None:  # type: ignore[no-untyped-def]
    """+/- zoom the window, n/N switch nodes, b sends baseline.measure to the focused daemon, which measures it."""
    hub = FeedHub([sim_daemon.control_endpoint, fake_node.control_endpoint])
    app = HdeemWatchApp(hub, fps=10, baseline_s=1.0)
    async with app.run_test(size=(100, 30)) as pilot:
        await until(lambda: "LIVE" in shown(app, HealthBar))
        assert "pilot" in shown(app, HealthBar) and "1/2" in shown(app, HealthBar)
        await pilot.press("minus")
        assert app.window_s == 120.0 and hub.view.window_s == 120.0
        await pilot.press("plus", "plus")
        assert app.window_s == 30.0 and "win 30s" in shown(app, HealthBar)
        await pilot.press("n")
        await until(lambda: "fake1" in shown(app, HealthBar) and "2/2" in shown(app, HealthBar))
        assert hub.view.focus == 1
        await pilot.press("N")
        await until(lambda: "pilot" in shown(app, HealthBar))
        with ControlClient(sim_daemon.control_endpoint) as client:
            before = client.call("baseline.get")["channels"].get("DDR_AB", {}).get("t_ns", 0)
        await pilot.press("b")
        await until(lambda: "baseline.measure: sent" in app.key_line)
        await until(lambda: "baseline.measure: ok" in app.key_line, timeout_s=20)
        assert not any(op == "baseline.measure" for op, _ in fake_node.requests)
        with ControlClient(sim_daemon.control_endpoint) as client:
            baselines = client.call("baseline.get")["channels"]
        assert set(baselines) >= {"DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH"}
        assert baselines["DDR_AB"]["t_ns"] > before
        await until(lambda: "±" in shown(app, ChannelTable).splitlines()[1])


@pytest.mark.slow
async def test_reconnects_after_the_daemon_is_killed_and_restarted(sim_daemon) -> None:  # type: ignore[no-untyped-def]
    """kill -9 of the daemon turns the screen STALE/RECONNECTING; a restarted daemon makes it LIVE again."""
    hub = FeedHub([sim_daemon.control_endpoint], stale_after_s=2.0, control_timeout_s=0.5)
    app = HdeemWatchApp(hub, fps=10)
    async with app.run_test(size=(80, 24)):
        await until(lambda: "LIVE" in shown(app, HealthBar))
        sim_daemon.kill()
        await until(lambda: "RECONNECTING" in shown(app, HealthBar) or "STALE" in shown(app, HealthBar))
        assert "LIVE" not in shown(app, HealthBar)
        assert app.screen.has_class("-stale")
        await asyncio.to_thread(sim_daemon.start)
        await until(lambda: "LIVE" in shown(app, HealthBar), timeout_s=20)
        await until(lambda: "restarts 1" in shown(app, HealthBar))
        before = dram_values(shown(app, ChannelTable))
        await until(lambda: dram_values(shown(app, ChannelTable)) != before)
        assert not app.screen.has_class("-stale")


def test_fake_node_is_not_the_daemon(fake_node: FakeNode) -> None:
    """The stand-in publisher answers only the UI's operations (it is no daemon)."""
    with ControlClient(fake_node.control_endpoint) as client:
        assert client.call("status")["node"] == "fake1"
        try:
            client.call("run.start", {"kernel": "read"})
        except Exception as error:  # ControlError
            assert "unknown-op" in str(error)
        else:
            raise AssertionError("run.start should be refused")
