"""Pure parts of the TUI: downsampling, ring buffers, the node model, records, text plots."""

from __future__ import annotations

import math

import numpy as np

from hdeem_watch.run_record import RunRecord
from hdeem_watch.tui.braille import braille_envelope, sparkline
from hdeem_watch.tui.downsample import minmax_columns
from hdeem_watch.tui.headless import ProgressPrinter
from hdeem_watch.tui.model import NodeModel
from hdeem_watch.tui.recent_samples import RecentSamples
from hdeem_watch.tui.records import calib_view, run_view
from hdeem_watch.wire import protocol

S = 1_000_000_000


def _samples(seq: int, t: np.ndarray, p: np.ndarray, channel: str = "DDR_AB", node: str = "n1") -> protocol.Message:
    frames = protocol.encode_samples(
        node, channel, seq=seq, rate_hz=100.0, t_wall_ns=t, power_w=p, energy_j=1.0, status="ok", t_ns=int(t[-1])
    )
    return protocol.decode(frames)


def _msg(kind: str, seq: int, body: dict, node: str = "n1") -> protocol.Message:
    topic = protocol.topic(node, kind)
    return protocol.decode(protocol.encode(topic, {"seq": seq, "node": node, "t_ns": 0, **body}))


def test_downsampling_keeps_spikes_and_dips() -> None:
    """A single-sample spike and dip among 100 000 samples survive as a column's max and min."""
    t = np.arange(100_000, dtype=np.int64) * 10_000_000
    p = np.full(100_000, 5.0)
    p[12_345] = 99.0
    p[77_777] = -3.0
    cols = minmax_columns(t, p, t0_ns=0, t1_ns=int(t[-1]) + 1, width=50)
    assert np.nanmax(cols.max_w) == 99.0
    assert np.nanmin(cols.min_w) == -3.0
    assert int(np.nanargmax(cols.max_w)) == 12_345 * 50 // 100_000
    assert np.allclose(np.nanmedian(cols.mean_w), 5.0)


def test_downsampling_unknown_stays_unknown() -> None:
    """Empty or all-NaN columns are NaN (unknown), never 0, and NaN never becomes min or max."""
    t = np.array([0, 1, 2, 3, 8, 9], dtype=np.int64)
    p = np.array([1.0, np.nan, 3.0, 2.0, np.nan, np.nan])
    cols = minmax_columns(t, p, t0_ns=0, t1_ns=10, width=5)
    assert cols.min_w[0] == 1.0 and cols.max_w[0] == 1.0  # [0, 2): 1.0 and NaN
    assert cols.min_w[1] == 2.0 and cols.max_w[1] == 3.0
    assert math.isnan(cols.min_w[2]) and math.isnan(cols.max_w[3])
    assert math.isnan(cols.max_w[4])  # only NaN samples


def test_ring_keeps_newest_in_order_across_wraps() -> None:
    """After many wrapping appends the ring holds exactly the newest ``capacity`` samples in order."""
    ring = RecentSamples(capacity=7)
    t_all = np.arange(40, dtype=np.int64)
    for lo, hi in [(0, 3), (3, 10), (10, 11), (11, 25), (25, 40)]:
        ring.extend(t_all[lo:hi], t_all[lo:hi].astype(float))
    t, p = ring.window(0, 100)
    assert t.tolist() == list(range(33, 40))
    assert p.tolist() == [float(x) for x in range(33, 40)]
    assert ring.last() == (39, 39.0)


def test_gap_counting_and_restart() -> None:
    """Skipped sequence numbers count as gaps; a sequence that restarts counts as a restart, not a gap."""
    model = NodeModel("ipc:///x")
    t = np.array([S], dtype=np.int64)
    for seq in (0, 1, 4, 5):  # 2 and 3 lost
        model.apply(_samples(seq, t + seq, np.array([5.0])), recv_mono_ns=0)
    model.apply(_msg("status", 0, {"uptime_s": 100.0}), recv_mono_ns=0)
    health = model.health(now_mono_ns=0)
    assert health.gaps == 2 and health.restarts == 0
    model.apply(_samples(0, t + 10, np.array([5.0])), recv_mono_ns=0)  # daemon restarted
    health = model.health(now_mono_ns=0)
    assert health.gaps == 2 and health.restarts == 1
    assert "restart" in health.detail


def test_staleness_from_silence() -> None:
    """A node is live while messages arrive and stale after 3 s of silence, with the age shown."""
    model = NodeModel("ipc:///x", stale_after_s=3.0)
    assert model.health(0).state == "connecting"
    model.apply(_samples(0, np.array([S]), np.array([5.0])), recv_mono_ns=10 * S)
    assert model.health(12 * S).state == "live"
    late = model.health(14 * S)
    assert late.state == "stale"
    assert late.last_rx_age_s == 4.0


def test_snapshot_values_baseline_and_above() -> None:
    """The current value is the recent mean; above-baseline is value minus the baseline message's power."""
    model = NodeModel("ipc:///x")
    t = S + np.arange(50, dtype=np.int64) * 10_000_000
    model.apply(_samples(0, t, np.full(50, 9.0)), 0)
    model.apply(_msg("baseline", 0, {"channels": {"DDR_AB": {"power_w": 6.0, "spread_w": 0.25, "origin": "idle-run"}}}), 0)
    snap = model.snapshot(now_mono_ns=0, now_wall_ns=int(t[-1]), window_s=1.0, width=20)
    ch = snap.channels[0]
    assert ch.power_w == 9.0 and ch.baseline_w == 6.0 and ch.above_w == 3.0
    assert ch.columns is not None and ch.columns.width == 20
    assert snap.health.state == "live"
    no_plot = model.snapshot(now_mono_ns=0, now_wall_ns=int(t[-1]), window_s=1.0, width=None)
    assert no_plot.channels[0].columns is None


def test_runs_in_progress_and_finished() -> None:
    """run start shows the run in progress; run stop moves it to the finished runs with its errors."""
    model = NodeModel("ipc:///x")
    record = {"run_id": "r1", "name": "triad-24t", "kernel": "triad", "threads": 24, "t_start_ns": 0, "state": "running"}
    model.apply(_msg("run", 0, {"event": "start", "run": record}), 0)
    snap = model.snapshot(now_mono_ns=0, now_wall_ns=2 * S, window_s=10, width=None)
    assert snap.current_run is not None and snap.current_run.running and snap.current_run.duration_s == 2.0
    done = {**record, "state": "done", "window_s": 1.5, "dram_energy_j": 10.0,
            "model": {"datasheet_j": 20.0, "calibrated_j": 10.5}, "metadata": {"simulated": True}}
    model.apply(_msg("run", 1, {"event": "stop", "run": done}), 0)
    snap = model.snapshot(now_mono_ns=0, now_wall_ns=2 * S, window_s=10, width=None)
    assert snap.current_run is None
    (run,) = snap.runs
    assert run.measured_j == 10.0 and run.simulated
    assert math.isclose(run.error_datasheet, 1.0) and math.isclose(run.error_calibrated, 0.05)


def test_run_record_measured_from_channels() -> None:
    """Without a total, the measured DRAM energy is the sum of the four DIMM-pair channels; a NaN one makes it unknown."""
    rec = {"run_id": "a", "state": "done", "kernel": "read", "energy_j": {"DDR_AB": 1.0, "DDR_CD": 2.0, "DDR_EF": 3.0, "DDR_GH": 4.0, "CPU0": 50.0}}
    assert run_view(RunRecord.from_dict(rec)).measured_j == 10.0
    rec["energy_j"]["DDR_GH"] = None
    assert math.isnan(run_view(RunRecord.from_dict(rec)).measured_j)


def test_calib_view_with_sim_truth_and_history() -> None:
    """Calibration: datasheet/calibrated/ci95/identifiable per current, errors, history, and the sim truth (marked)."""
    fit = {
        "currents": {
            "idd0": {"datasheet": 0.058, "calibrated": 0.031, "ci95": [0.029, 0.033], "identifiable": True},
            "idd5b": {"datasheet": 0.25, "calibrated": 0.24, "ci95": [0.1, 0.3], "identifiable": False},
        },
        "error": {"before": 0.98, "after": 0.03, "loo": 0.045},
    }
    truth = {"simulated": True, "datasheet": {"idd0": 0.058}, "mean_currents_a": {"idd0": 0.030, "idd5b": 0.2}}
    history = [[1, {"currents": {"idd0": {"calibrated": 0.05}}}], [2, fit]]
    view = calib_view({"fit": fit, "history": history, "truth": truth, "suggest": [["read-24t", 0.7]]})
    idd0, idd5b = view.currents
    assert (idd0.datasheet_a, idd0.calibrated_a, idd0.identifiable) == (0.058, 0.031, True)
    assert math.isclose(idd0.ci95_a, 0.002)
    assert idd0.truth_a == 0.030 and idd0.history_a == (0.05, 0.031)
    assert math.isclose(idd5b.ci95_a, 0.1) and not idd5b.identifiable
    assert view.simulated and view.error_loo == 0.045 and view.suggested_next == "read-24t"
    assert calib_view({"fit": None}).currents == ()


def test_braille_envelope_fills_min_to_max() -> None:
    """A data column spanning the full range lights every dot of its half-cell; a NaN column stays blank."""
    rows = braille_envelope(np.array([0.0, np.nan]), np.array([1.0, np.nan]), lo=0.0, hi=1.0, height=2)
    assert rows == ["⡇", "⡇"]
    assert sparkline([1.0, math.nan, 3.0]) == "▁ █"


def test_headless_printer_reports_new_runs_and_calibration_once() -> None:
    """The text progress prints each finished run and each new calibration once."""
    model = NodeModel("ipc:///x")
    model.apply(_msg("run", 0, {"event": "stop", "run": {"run_id": "r1", "state": "done", "kernel": "copy", "threads": 24,
                                                          "window_s": 1.5, "dram_energy_j": 10.0}}), 0)
    model.apply(_msg("calib", 0, {"fit": {"currents": {"idd0": {"datasheet": 0.05, "calibrated": 0.03}},
                                          "error": {"before": 1.0, "after": 0.02}, "n_runs": 3, "dof": 2}}), 0)
    printer = ProgressPrinter(power_every_s=60)
    snap = model.snapshot(now_mono_ns=0, now_wall_ns=0, window_s=10, width=None)
    lines = printer.lines(snap, now_s=0.0)
    assert any(line.startswith("run ") and "copy" in line and "10.00 J" in line for line in lines)
    assert any(line.startswith("calib ") and "idd0 50.0->30.0" in line and "after 2.0%" in line for line in lines)
    assert [line for line in printer.lines(snap, now_s=1.0) if not line.startswith("power")] == []


def test_column_cache_matches_a_fresh_computation_as_data_arrives() -> None:
    """Cached complete columns plus fresh ones equal a full recomputation over the same aligned window."""
    from hdeem_watch.tui.downsample import ColumnCache

    rng = np.random.default_rng(1)
    ring = RecentSamples(capacity=100_000)
    cache = ColumnCache()
    t_all = np.arange(30_000, dtype=np.int64) * 1_000_000 + 7  # 1 kHz, 30 s
    p_all = rng.normal(10.0, 2.0, len(t_all))
    p_all[rng.integers(0, len(p_all), 50)] = np.nan
    for lo in range(0, len(t_all), 100):  # batches of 100 ms
        ring.extend(t_all[lo : lo + 100], p_all[lo : lo + 100])
        newest = ring.newest_t_ns()
        got = cache.columns(ring.window, t1_ns=newest, window_ns=10 * S, width=37, newest_ns=newest)
    fresh_t, fresh_p = ring.window(got.t0_ns, got.t1_ns)
    want = minmax_columns(fresh_t, fresh_p, t0_ns=got.t0_ns, t1_ns=got.t1_ns, width=37)
    assert got.t1_ns > t_all[-1] and got.t1_ns - got.t0_ns >= 10 * S
    np.testing.assert_array_equal(got.min_w, want.min_w)
    np.testing.assert_array_equal(got.max_w, want.max_w)
    np.testing.assert_allclose(got.mean_w, want.mean_w)


def test_samples_ahead_of_the_clock_are_plotted() -> None:
    """A daemon whose sample times run ahead of this clock (the sim at --speed 10, a host clock ahead):
    the plot ends at its newest sample (it was drawn empty: every sample lay right of 'now')."""
    model = NodeModel("ipc:///x", stale_after_s=3.0)
    t = 100 * S + np.arange(50, dtype=np.int64) * 10_000_000
    model.apply(_samples(0, t, np.full(50, 2.0)), 0)
    behind = int(t[-1]) - 60 * S  # this host's clock, a minute behind the samples
    columns = model.snapshot(now_mono_ns=0, now_wall_ns=behind, window_s=0.4, width=10).channels[0].columns
    assert columns is not None and np.isfinite(columns.mean_w).sum() >= 9
    silent = model.snapshot(now_mono_ns=0, now_wall_ns=int(t[-1]) + 60 * S, window_s=0.4, width=10)
    assert silent.channels[0].columns is not None and not np.isfinite(silent.channels[0].columns.mean_w).any()
