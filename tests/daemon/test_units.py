"""Pure parts of the daemon: deadlines, gaps, baselines, windows, run records, store, control dispatch, metrics."""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from hdeem_watch.daemon.book import baselines as bl
from hdeem_watch.daemon.book.channels import ChannelAccount, RecentPower, count_missing
from hdeem_watch.daemon.book.runs import parse_run_args, started_run, window_energy
from hdeem_watch.daemon.book.windows import Window
from hdeem_watch.daemon.shell.control import OpError, Pending, dispatch
from hdeem_watch.daemon.shell.metrics import DaemonMetrics, NodeCollector
from hdeem_watch.daemon.shell.poller import IntervalTimer, next_deadline, wait_ms
from hdeem_watch.daemon.store.database import SCHEMA_VERSION, Store, StoreError
from hdeem_watch.run_record import RunRecord
from hdeem_watch.wire.protocol import ProtocolError, decode_reply
from hdeem_watch.wire.protocol import jsonable as protocol_jsonable


@given(st.integers(0, 10**12), st.integers(1, 10**9), st.integers(0, 10**12))
def test_next_deadline_skips_missed_ticks(start: int, interval: int, now: int) -> None:
    """The next deadline is on the start's grid, strictly after now, and at most one interval away."""
    deadline, skipped = next_deadline(start, interval, now)
    assert (deadline - start) % interval == 0
    assert deadline > now or (now < start and deadline == start + interval)
    if now >= start:
        assert deadline - now <= interval
        assert skipped == (deadline - start) // interval - 1


def test_interval_timer_never_bursts() -> None:
    """After a stall of many periods the timer serves one tick and moves to the next future deadline."""
    now = [0]
    timer = IntervalTimer(10, clock=lambda: now[0])
    now[0] = 1005
    assert timer.due() and timer.advance() == 99 and timer.next_ns == 1010
    assert not timer.due() and timer.remaining_ns() == 5
    assert wait_ms([timer]) == 1 and wait_ms([]) == 1000


def test_count_missing_from_timestamps() -> None:
    """Missing samples are counted from steps larger than 1.5 periods, also across batches."""
    period = 10_000_000
    t = np.array([1, 2, 3, 6, 7], dtype=np.int64) * period
    assert count_missing(t, rate_hz=100.0, prev_t_ns=None) == 2
    assert count_missing(t, rate_hz=100.0, prev_t_ns=-2 * period) == 4
    assert count_missing(t[:3], rate_hz=100.0, prev_t_ns=0) == 0


def test_channel_account_energy_rate_and_gaps() -> None:
    """The account tracks cumulative energy deltas, the rate in sample time and reported gaps."""
    acc = ChannelAccount("DDR_AB", 100.0, "dram", history_s=1.0)
    t = np.arange(1, 51, dtype=np.int64) * 10_000_000
    assert acc.update(t, np.full(50, 2.0), energy_j=1.0, status="ok") == (50, 0, 1.0)
    n, missing, delta = acc.update(t[-1] + np.arange(2, 52) * 10_000_000, np.full(50, 3.0), energy_j=2.5,
                                   status="gap", reported_missing=1)
    assert (n, missing, delta) == (50, 1, 1.5)
    assert acc.close_rate_window() == pytest.approx(100.0, rel=0.02)
    assert acc.gaps == 1 and acc.status == "gap" and len(acc.history) == 100


def test_sample_ring_keeps_the_newest() -> None:
    """The ring returns the last capacity values, oldest first, across wrap-arounds."""
    ring = RecentPower(5)
    ring.extend(np.arange(3.0))
    ring.extend(np.arange(3.0, 7.0))
    assert ring.values().tolist() == [2.0, 3.0, 4.0, 5.0, 6.0]
    ring.extend(np.arange(100.0))
    assert ring.values().tolist() == [95.0, 96.0, 97.0, 98.0, 99.0]


def test_quiet_window_prefers_the_lowest_quiet_level() -> None:
    """Among windows with a small spread the lowest mean wins; noisy or NaN windows are never quiet."""
    rng = np.random.default_rng(1)
    p = np.r_[np.full(300, 8.0), 3.0 + rng.normal(0, 0.05, 300), 1.0 + rng.normal(0, 2.0, 300), [np.nan] * 50]
    start, stop = bl.quiet_window(p, rate_hz=100.0, window_s=1.0, max_spread_w=0.2)
    assert start >= 300 and stop <= 600
    assert bl.quiet_window(rng.normal(5, 3, 500), rate_hz=100.0, window_s=1.0, max_spread_w=0.2) is None
    b = bl.baseline_from_samples(p[start:stop], t_ns=7, origin="quiet")
    assert b.power_w == pytest.approx(3.0, abs=0.05) and b.spread_w == pytest.approx(0.05, rel=0.3)


def test_window_stats_match_numpy() -> None:
    """The O(n) sliding mean/std equals numpy's per-window figures."""
    rng = np.random.default_rng(2)
    p = 1000.0 + rng.normal(0, 1, 1000)
    starts, mean, std = bl.window_stats(p, 100, 37)
    for s, m, d in zip(starts, mean, std):
        assert m == pytest.approx(p[s:s + 100].mean(), rel=1e-12)
        assert d == pytest.approx(p[s:s + 100].std(), rel=1e-6)


def test_baseline_merge_policy() -> None:
    """Idle runs replace anything; a quiet level replaces a higher quiet one or a stale idle run only."""
    idle = bl.Baseline(5.0, 0.1, 100, 0, "idle-run")
    quiet_low = bl.Baseline(4.0, 0.1, 100, 10, "quiet")
    assert bl.merge(idle, quiet_low) is idle
    assert bl.merge(None, quiet_low) is quiet_low
    assert bl.merge(quiet_low, bl.Baseline(4.5, 0.1, 100, 20, "quiet")) is quiet_low
    newer_idle = bl.Baseline(6.0, 0.1, 100, 30, "idle-run")
    assert bl.merge(quiet_low, newer_idle) is newer_idle
    stale = bl.Baseline(7.0, 0.1, 100, 10**13, "quiet")
    assert bl.merge(idle, stale) is stale
    assert bl.merge(idle, bl.Baseline(math.nan, math.nan, 0, 50, "idle-run")) is idle
    assert bl.Baseline.from_dict(json.loads(json.dumps(idle.to_dict()))) == idle
    measured = bl.Baseline(3.5, 0.1, 100, 40, "measured")  # baseline.measure: an explicit window too
    assert bl.merge(newer_idle, measured) is measured and bl.merge(measured, quiet_low) is measured
    assert bl.Baseline.from_dict(measured.to_dict()) == measured


def test_idle_baseline_mean_from_exact_energy() -> None:
    """With the window's energy the mean is energy / duration, not the (possibly gappy) sample mean."""
    b = bl.baseline_from_samples(np.array([1.0, 3.0]), t_ns=0, origin="idle-run", energy_j=10.0, window_s=4.0)
    assert b.power_w == 2.5 and b.spread_w == 1.0 and b.n == 2


def test_window_cuts_each_channel_at_the_stop() -> None:
    """A window ends at the target: samples after the one containing it are taken back out of the total."""
    ms = 1_000_000
    w = Window(kind="run", start_energy_j={"DDR_AB": 10.0, "BLADE": 100.0}, start_t_ns={"DDR_AB": 0, "BLADE": 0},
               dram_channels=("DDR_AB",), t_start_mono_ns=0)
    w.observe("DDR_AB", np.array([10, 20]) * ms, np.array([100.0, 100.0]), energy_j=12.0)  # still open
    w.request_close(target_t_ns=25 * ms, deadline_mono_ns=10**9, rates_hz={"DDR_AB": 100.0, "BLADE": 1000.0})
    assert not w.ready(0)
    # One late batch carries the samples around the stop: 30 (contains 25) is kept, 40 and 50 are not.
    w.observe("DDR_AB", np.array([30, 40, 50]) * ms, np.array([100.0, 200.0, 300.0]), energy_j=18.0)
    w.observe("BLADE", np.arange(1, 41) * ms, np.full(40, 1000.0), energy_j=140.0)
    assert w.ready(0)
    energy, window_s, spans = w.result({"DDR_AB": 18.0, "BLADE": 140.0}, {"DDR_AB": 50 * ms, "BLADE": 40 * ms},
                                       now_mono_ns=ms, speed=1.0)
    assert energy == pytest.approx({"DDR_AB": 3.0, "BLADE": 25.0})
    assert window_s == pytest.approx(0.03) and spans["BLADE"] == pytest.approx(0.025)
    assert w.channel_samples("DDR_AB").tolist() == [100.0, 100.0, 100.0]


def test_window_deadline_and_unknown_values() -> None:
    """A stalled channel closes the window at the deadline; a NaN after the stop keeps the whole total."""
    w = Window(kind="run", start_energy_j={"DDR_AB": 0.0, "DDR_CD": 0.0}, start_t_ns={"DDR_AB": 0, "DDR_CD": 0},
               dram_channels=("DDR_AB", "DDR_CD"), t_start_mono_ns=0)
    w.request_close(target_t_ns=15, deadline_mono_ns=100, rates_hz={"DDR_AB": 1e8, "DDR_CD": 1e8})
    w.observe("DDR_AB", np.array([10, 20, 30]), np.array([1e8, 1e8, np.nan]), energy_j=5.0)
    assert w.cut["DDR_AB"] == (5.0, 30)
    assert not w.ready(99) and w.ready(100)
    energy, _, _ = w.result({"DDR_AB": 5.0, "DDR_CD": 0.5}, {"DDR_AB": 30, "DDR_CD": 10}, now_mono_ns=100, speed=2.0)
    assert energy == {"DDR_AB": 5.0, "DDR_CD": 0.5}


def test_run_records() -> None:
    """run.start arguments are validated; a finished record has energies, mean powers and the DRAM sum."""
    args = parse_run_args({"kernel": " Triad ", "threads": 24, "elements": 10, "metadata": {"a": 1}})
    assert (args.kernel, args.threads, args.repeat, args.name) == ("triad", 24, 1, "triad")
    for bad in ({"kernel": ""}, {"kernel": "x", "threads": 1.5}, {"kernel": "x", "repeat": 0},
                {"kernel": "x", "elements": True}, {"kernel": "x", "name": 5}):
        with pytest.raises(ProtocolError) as info:
            parse_run_args(bad)
        assert info.value.code == "bad-args"
    record = started_run("r3", args, t_wall_ns=1, node="n")
    energy = window_energy({"DDR_AB": 1.0, "DDR_CD": 1.0, "CPU0": math.nan}, {"DDR_AB": 3.0, "DDR_CD": 5.0, "CPU0": 9.0})
    done = record.finish(energy_j=energy, window_s=2.0, dram_channels=("DDR_AB", "DDR_CD"), t_wall_ns=9)
    assert done.dram_energy_j == 6.0 and done.mean_power_w is not None and done.mean_power_w["DDR_CD"] == 2.0
    assert done.state == "modelling" and record.state == "running"
    assert done.energy_j is not None and math.isnan(done.energy_j["CPU0"])
    assert RunRecord.from_dict(json.loads(json.dumps(protocol_jsonable(done.to_dict())))).dram_energy_j == 6.0


def test_dispatch_answers_everything() -> None:
    """Handler errors become error replies with their codes; a crashing handler is an internal error."""

    def boom(args: dict) -> None:
        raise ZeroDivisionError("x")

    def refuse(args: dict) -> None:
        raise OpError("conflict", "busy")

    handlers = {"boom": boom, "refuse": refuse, "later": lambda args: Pending("later")}
    assert decode_reply(dispatch(b'{"id": 1, "op": "boom"}', handlers)).code == "internal"  # type: ignore[arg-type]
    assert decode_reply(dispatch(b'{"id": 1, "op": "refuse"}', handlers)).code == "conflict"  # type: ignore[arg-type]
    pending = dispatch(b'{"id": "p", "op": "later"}', handlers)
    assert isinstance(pending, Pending) and pending.request_id == "p"


def test_metrics_follow_prometheus_naming() -> None:
    """Power is a gauge in watts, energy a counter in joules with _total, read at scrape time from the accounts."""
    account = ChannelAccount("DDR_AB", 100.0, "dram")
    account.update(np.array([10_000_000]), np.array([4.0]), energy_j=2.0, status="ok")
    account.gaps = 1
    fit: dict = {"currents": {"idd0": {"calibrated": 0.05}}, "error": {"after": 0.03}}
    m = DaemonMetrics(NodeCollector("n1", accounts=lambda: {"DDR_AB": account}, baselines=lambda: {},
                                    fit=lambda: fit, runs_finished=lambda: 2))
    text = m.exposition().decode()
    assert 'hdeem_watch_energy_joules_total{channel="DDR_AB",node="n1"} 2.0' in text
    assert 'hdeem_watch_missing_samples_total{channel="DDR_AB",node="n1"} 1.0' in text
    assert 'hdeem_watch_calibrated_current_amperes{current="idd0",node="n1"} 0.05' in text
    assert 'hdeem_watch_runs_total{node="n1"} 2.0' in text
    assert "# TYPE hdeem_watch_power_watts gauge" in text
    assert "process_cpu_seconds_total" in text
    # Unknown energy later: the counter holds its last value (a counter never goes down or NaN).
    account.update(np.array([20_000_000]), np.array([np.nan]), energy_j=math.nan, status="stale")
    account.update(np.array([30_000_000]), np.array([5.0]), energy_j=3.5, status="ok")
    assert 'hdeem_watch_energy_joules_total{channel="DDR_AB",node="n1"} 3.5' in m.exposition().decode()


def test_store_round_trip_and_schema_guard(tmp_path: Path) -> None:
    """Runs, calibration and baselines round-trip with NaN as null; a newer schema is refused."""
    store = Store(tmp_path / "s.db")
    assert store.next_run_id() == "r1"
    store.save_run({"run_id": "r1", "kernel": "read", "state": "running", "t_start_ns": 5, "x": math.nan})
    store.save_run({"run_id": "r2", "kernel": "idle", "state": "done", "t_start_ns": 6})
    assert store.next_run_id() == "r3" and store.get_run("r1") == {"run_id": "r1", "kernel": "read",
                                                                    "state": "running", "t_start_ns": 5, "x": None}
    assert store.close_interrupted_runs(9) == 1 and store.get_run("r1")["state"] == "aborted"
    assert [r["run_id"] for r in store.list_runs(kernel="idle")] == ["r2"]
    store.save_calibration(7, {"state": 1}, {"n_runs": 1}, "r2")
    store.clear_calibrator(8)
    assert store.load_calibrator() is None and [f for _, _, f in store.fit_history()] == [{"n_runs": 1}, None]
    store.save_baseline("DDR_AB", {"power_w": 3.0, "t_ns": 4})
    assert store.load_baselines() == {"DDR_AB": {"power_w": 3.0, "t_ns": 4}}
    assert store.schema_version == SCHEMA_VERSION
    store._db.execute("UPDATE meta SET value = '99' WHERE key = 'schema_version'")
    store.close()
    with pytest.raises(StoreError):
        Store(tmp_path / "s.db")


WRITER = """
import sys
from hdeem_watch.daemon.store.database import Store
store = Store(sys.argv[1])
i = 0
while True:
    i += 1
    store.save_run({"run_id": f"r{i}", "kernel": "triad", "state": "done", "t_start_ns": i})
    print(i, flush=True)
"""


@pytest.mark.slow
def test_store_survives_kill9_mid_write(tmp_path: Path) -> None:
    """Every run a writer reported as saved is readable after the writer is killed with SIGKILL mid-stream."""
    path = tmp_path / "state.db"
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    acknowledged = 0
    deadline = time.monotonic() + 20
    while acknowledged < 50 and time.monotonic() < deadline:
        acknowledged = int(proc.stdout.readline())
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    store = Store(path)
    try:
        assert store.count_runs() >= acknowledged >= 50
        assert store.get_run(f"r{acknowledged}") is not None
    finally:
        store.close()  # its writer thread must not outlive the test (a forked pipeline worker checks)


def test_interval_change_takes_effect_within_one_new_period() -> None:
    """Switching to a faster period moves the next deadline closer; a slower one does not delay it."""
    now = [0]
    timer = IntervalTimer(250, clock=lambda: now[0])
    now[0] = 10
    timer.set_interval(25)
    assert timer.next_ns == 35
    timer.set_interval(250)
    assert timer.next_ns == 35 and timer.interval_ns == 250


@pytest.mark.parametrize("name", [[], {}, 0, False])
def test_run_start_refuses_a_name_that_is_no_string(name: object) -> None:
    """Issue 28: a `name` of [], {}, 0 or false was silently replaced by the kernel's name; it is
    refused naming the argument (absent, null or "" still mean the kernel's name)."""
    with pytest.raises(ProtocolError, match=r"args.name = .*: expected a string"):
        parse_run_args({"kernel": "triad", "name": name})
    for absent in ({}, {"name": None}, {"name": ""}):
        assert parse_run_args({"kernel": "triad", **absent}).name == "triad"
