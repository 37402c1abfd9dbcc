"""What the screen says at 80×24, from frozen and hand-built snapshots (pilot, no daemon)."""

from __future__ import annotations

import math
import re

from hdeem_watch.tui.app import HELP_TEXT, HdeemWatchApp
from hdeem_watch.tui.model import NodeModel
from hdeem_watch.tui.provider import StaticProvider
from hdeem_watch.tui.records import calib_view
from hdeem_watch.tui.snapshot import ChannelView, HealthView, NodeSnapshot
from hdeem_watch.tui.widgets import CalibPanel, HealthBar, PowerPlots, RunsPanel
from hdeem_watch.tui.widgets.calib import calib_text
from hdeem_watch.tui.widgets.channels import channel_table_text


def _frozen_app(build) -> tuple[HdeemWatchApp, NodeSnapshot]:  # type: ignore[no-untyped-def]
    snap = build(plot_cells=80 // 2 - 8)
    return HdeemWatchApp(StaticProvider([snap]), fps=2, clock=lambda: snap.built_mono_ns), snap


def _channel(name: str, kind: str, power_w: float, baseline_w: float, origin: str) -> ChannelView:
    return ChannelView(name=name, kind=kind, rate_hz=100.0, power_w=power_w, baseline_w=baseline_w, spread_w=1.0,
                       baseline_origin=origin, energy_j=math.nan, status="ok", source_gaps=0)


def test_above_is_shown_only_against_a_true_idle_baseline() -> None:
    """CPU/BLADE baselines from idle runs (threads spinning) are no idle: "above" is "–" there, not
    −17 W; a DRAM channel's idle-run baseline and a quiet baseline of any channel are idle."""
    snap = NodeSnapshot(node="n", built_mono_ns=1, window_s=60, channels=(
        _channel("DDR_AB", "dram", 2.5, 1.7, "idle-run"),
        _channel("CPU0", "cpu", 12.3, 29.8, "idle-run"),
        _channel("CPU1", "cpu", 14.0, 11.9, "quiet"),
        _channel("BLADE", "blade", 72.0, 107.3, "idle-run"),
    ))
    rows = {line.split()[0]: line.split()[-1] for line in channel_table_text(snap, 40).plain.splitlines()[1:]}
    assert rows == {"DDR_AB": "+0.8", "CPU0": "–", "CPU1": "+2.1", "BLADE": "–"}


async def test_every_strip_shows_its_range_at_80x24(frozen_snapshot) -> None:  # type: ignore[no-untyped-def]
    """Each of the seven strips, BLADE included, has a row with its range "lo–hi" under its name."""
    app, snap = _frozen_app(frozen_snapshot)
    async with app.run_test(size=(80, 24)) as pilot:
        await pilot.pause()
        app.paint()
        lines = app.query_one(PowerPlots).plain.splitlines()
        for channel in snap.channels:
            row = next(i for i, line in enumerate(lines) if line.startswith(channel.name))
            label = lines[row + 1][:8].strip()
            lo, hi = (float(v) for v in label.split("–"))
            assert lo < channel.power_w < hi, (channel.name, label)


async def test_the_health_bar_keeps_the_reason_at_80x24() -> None:
    """A node that is not live says why in full on an 80-column bar, even with a long ipc endpoint."""
    health = HealthView(state="connecting", endpoint="ipc:///tmp/hdeem-watch-demo-k2j3h4/control.sock",
                        detail="control answers, but nothing arrives")
    snap = NodeSnapshot(node="?", built_mono_ns=1, window_s=60, health=health)
    app = HdeemWatchApp(StaticProvider([snap]), fps=2, clock=lambda: 1)
    async with app.run_test(size=(80, 24)) as pilot:
        await pilot.pause()
        app.paint()
        assert "control answers, but nothing arrives" in app.query_one(HealthBar).plain


def test_runs_title_counts_every_run_not_the_50_shown() -> None:
    """With 57 runs finished, the panel says 57 although the snapshot carries the newest 50."""
    model = NodeModel("ipc:///x")
    model.apply_status({"runs": 55, "uptime_s": 10.0, "t_ns": 10**18})
    model.add_runs([{"run_id": f"r{i}", "state": "done", "kernel": "copy", "threads": 1, "window_s": 1.0, "dram_energy_j": 1.0}
                    for i in range(55)], history=True)
    for i in (55, 56):
        model.apply_run_event({"event": "stop", "run": {"run_id": f"r{i}", "state": "done", "kernel": "read", "dram_energy_j": 1.0}})
    snap = model.snapshot(now_mono_ns=0, now_wall_ns=10**18, window_s=60, width=None)
    assert len(snap.runs) == 50 and snap.runs_total == 57
    from hdeem_watch.tui.widgets.runs import runs_text

    assert runs_text(snap, 40, 10).plain.startswith("runs (57)")


def test_calibration_title_singular_and_the_suggestion_labelled() -> None:
    """"calibration (1 run)", and the daemon's next-run pick is labelled a suggestion."""
    fit = {"currents": {"idd0": {"datasheet": 0.06, "calibrated": 0.05}}, "n_runs": 1, "dof": 0,
           "error": {"before": 0.5, "after": 0.0, "loo": 23.79}}
    text = calib_text(calib_view({"fit": fit, "suggest": [["read-1t", 0.3]]}), 40).plain
    assert text.startswith("calibration (1 run)") and "(1 runs)" not in text
    assert "suggested run: read-1t" in text and "next run:" not in text


def test_an_undetermined_fit_shows_no_after_or_loo_error() -> None:
    """Fewer runs than unknowns: "after" and "loo" are "–" (not 0.0 % and 2379 %); determined: shown."""
    currents = {n: {"datasheet": 0.06, "calibrated": 0.05} for n in ("idd0", "idd2n", "idd3n", "idd4r", "idd4w")}
    under = {"currents": currents, "n_runs": 3, "dof": -3, "error": {"before": 0.5, "after": 0.0, "loo": 23.79}}
    text = calib_text(calib_view({"fit": under}), 60).plain
    assert "after – loo –" in text and "2379" not in text and "after 0.0%" not in text
    done = {**under, "n_runs": 9, "dof": 3, "error": {"before": 0.5, "after": 0.012, "loo": 0.02}}
    assert "after 1.2% loo 2.0%" in calib_text(calib_view({"fit": done}), 60).plain


def test_help_explains_every_column_and_the_stop_key() -> None:
    """? explains above, ds %, cal %, loo and the s key, and fits an 80×24 screen."""
    plain = re.sub(r"\[/?b\]", "", HELP_TEXT)
    for word in ("above", "ds %", "cal %", "loo", "s          stop"):
        assert word in plain, word
    assert len(plain.splitlines()) <= 22 and max(len(line) for line in plain.splitlines()) <= 68


async def test_s_stops_the_run_in_progress_and_says_when_there_is_none(frozen_snapshot) -> None:  # type: ignore[no-untyped-def]
    """s asks the daemon to abort the run in progress; with no run it says so on the key line."""
    app, snap = _frozen_app(frozen_snapshot)
    provider = app.provider
    assert isinstance(provider, StaticProvider) and snap.current_run is not None
    async with app.run_test(size=(80, 24)) as pilot:
        await pilot.press("s")
        assert provider.requests == [(0, "run.stop", {"run_id": snap.current_run.run_id, "abort": True})]
    idle = NodeSnapshot(node="n", built_mono_ns=1, window_s=60)
    app = HdeemWatchApp(StaticProvider([idle]), fps=2, clock=lambda: 1)
    async with app.run_test(size=(80, 24)) as pilot:
        await pilot.press("s")
        assert "no run in progress" in app.key_line
        assert app.provider.requests == []  # type: ignore[attr-defined]


def test_a_conflict_reply_names_the_key_that_stops_the_run() -> None:
    """b during a run: the daemon's conflict reply is shown with the hint that s stops the run."""
    from hdeem_watch.tui.messages import RequestFailed

    notice = RequestFailed("baseline.measure", "conflict", "run r12 is in progress; stop it first").notice
    assert notice.endswith("(s stops it)")


async def test_panels_fit_80x24(frozen_snapshot) -> None:  # type: ignore[no-untyped-def]
    """At 80×24 the calibration and runs panels are there and nothing is wrapped."""
    app, _ = _frozen_app(frozen_snapshot)
    async with app.run_test(size=(80, 24)) as pilot:
        await pilot.pause()
        app.paint()
        assert app.query_one(CalibPanel).plain.startswith("calibration (8 runs)")
        assert app.query_one(RunsPanel).plain.startswith("runs (8)")




def test_the_wide_runs_header_keeps_its_columns_apart() -> None:
    """Issue 28: at 120 columns the runs header read `ds errcal err`; every column name stands
    apart, right above its numbers."""
    model = NodeModel("ipc:///x")
    model.apply_status({"runs": 1, "uptime_s": 10.0, "t_ns": 10**18})
    model.apply_run_event({"event": "stop", "run": {
        "run_id": "r1", "state": "done", "kernel": "triad", "threads": 24, "window_s": 2.0, "dram_energy_j": 61.2,
        "model": {"datasheet_j": 120.0, "calibrated_j": 60.0}}})
    snap = model.snapshot(now_mono_ns=0, now_wall_ns=10**18, window_s=60, width=None)
    from hdeem_watch.tui.widgets.runs import runs_text

    lines = runs_text(snap, 120, 10).plain.splitlines()
    header, row = lines[1], lines[2]
    assert header.split() == ["kernel", "thr", "dur", "meas", "J", "ds", "J", "cal", "J", "ds", "err", "cal", "err"]
    for name in ("ds err", "cal err"):  # each right-aligned over its column's last character
        end = header.index(name) + len(name)
        assert row[end - 1] != " " and (end == len(row) or row[end] == " ")
