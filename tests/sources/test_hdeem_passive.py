"""HDEEM used as its own tools use it: passive by default, owning only when told, real sample times.

The fake libhdeem (fake_hdeem/) records every API call. Public monitors never start, clear or stop
the measurement: tud-zih-energy/metricq-source-hdeem src/hdeem_connection.cpp calls only
get_stats_total, and tud-zih-energy/hdeem_cxx include/hdeem_cxx.hpp says get_stats_total needs no
start or stop. Sample times follow score-p/scorep_plugin_hdeem hdeem_plugin.cpp: periods measured as
duration / samples from hdeem_status_t's start_time_blade, VR samples shifted by -(35000 - 5600) us.
The fake samples at the rates measured on Taurus (tests/data/taurus/6415.txt: 1003.074324
and 98.663048 Sa/s), not the nominal 1000 / 100.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zmq

from hdeem_watch.errors import InputError
from hdeem_watch.sources.base import SourceUnavailable
from hdeem_watch.sources.hdeem import HdeemSource
from hdeem_watch.sources.hdeem_lib import (
    BMC_OVERFLOW,
    FEATURE_GLOBAL,
    FEATURE_STATUS_TIMES,
    ShimLib,
    build_shim,
    shim_build_notes,
)

OWNERSHIP_CALLS = {"start", "clear", "stop"}
SRC = Path(__file__).resolve().parents[2] / "src"
LEGACY = Path(__file__).resolve().parent / "fake_hdeem" / "legacy"



def test_passive_energy_source_never_starts_clears_or_stops(fake_hdeem):
    """Default (passive): open, polls, a reconnect and close make none of hdeem_start/clear/stop;
    with no measurement running, health says so and the totals still give power."""
    src = HdeemSource(**fake_hdeem.options(interval_s=0.0))
    src.open()
    fake_hdeem.set_power(3, 2.5)
    for _ in range(3):
        fake_hdeem.advance(0.5)
        batch = src.poll()
    assert batch.samples["DDR_AB"][1][0] == pytest.approx(2.5, abs=0.02)
    assert "no HDEEM measurement running" in src.health()
    fake_hdeem.control("fail_calls", 1)          # a lost connection and the reconnect
    src.poll()
    src._retry_at = 0
    src.poll()
    src.close()
    calls = fake_hdeem.calls()
    assert {"init", "get_stats_total", "close"} <= set(calls) and calls.count("init") == 2
    assert not OWNERSHIP_CALLS & set(calls), calls
    assert fake_hdeem.control("running") == 0


def test_passive_global_reads_a_users_measurement_and_leaves_it_running(fake_hdeem):
    """Passive global: no samples and an 'idle' health while nobody measures; a measurement a user
    starts is read, and stays running after close."""
    src = HdeemSource(**fake_hdeem.options(interval_s=0.0, method="global"))
    src.open()
    fake_hdeem.advance(0.3)
    empty = src.poll()
    assert empty.n_samples() == 0 and src.health().startswith("idle: no HDEEM measurement running")
    fake_hdeem.control("run_external", 1)         # e.g. Score-P's HDEEM plugin starts one
    fake_hdeem.advance(0.3)
    src._last_status_ns = -(1 << 62)
    batch = src.poll()
    assert 290 <= len(batch.samples["BLADE"][0]) <= 600 and src.health() == "ok"
    src.close()
    assert not OWNERSHIP_CALLS & set(fake_hdeem.calls())
    assert fake_hdeem.control("running") == 1


def test_owning_mode_rearms_before_the_bmc_buffer_overflows(fake_hdeem, fake_clock):
    """hdeem_own_measurement: started at open, re-armed every rearm_s (< 8 h), stopped at close; over
    20 hours of fake time the BMC's 8-hour buffer never overflows (it would without re-arming)."""
    clock = fake_clock()
    src = HdeemSource(**fake_hdeem.options(interval_s=0.0, own_measurement=True, clock=clock))
    src.open()
    assert fake_hdeem.control("running") == 1
    overflowed = []
    for _ in range(20):
        fake_hdeem.advance(3600.0)
        clock.t += 3600 * 10**9
        batch = src.poll()
        overflowed.append(bool(src.lib.status(src._handle).flags & BMC_OVERFLOW))
        assert batch.status["DDR_AB"] == "ok"
    src.close()
    calls = fake_hdeem.calls()
    assert not any(overflowed)
    assert src.rearms == 5 and calls.count("start") == 6 and calls.count("clear") == 5
    last_stop = len(calls) - 1 - calls[::-1].index("stop")
    assert calls[-1] == "close" and last_stop > len(calls) - 1 - calls[::-1].index("start")
    assert fake_hdeem.control("running") == 0
    # the fake does overflow a measurement left running past 8 h: the check above can fail
    fake_hdeem.control("run_external", 1)
    fake_hdeem.advance(9 * 3600.0)
    lib = ShimLib(src.lib.path)
    handle = lib.open()
    assert lib.status(handle).flags & BMC_OVERFLOW
    lib.close(handle)


def test_rearm_period_must_stay_inside_the_bmc_buffer(fake_hdeem):
    """rearm_s >= 8 h cannot prevent the overflow: rejected with the key and the limit."""
    with pytest.raises(InputError, match=r"rearm_s = 30000.*8 hours"):
        HdeemSource(**fake_hdeem.options(own_measurement=True, rearm_s=30000))


def test_global_windows_exact_to_the_sample_with_real_rates(fake_hdeem):
    """With real rates 1003.07 / 98.66 Sa/s and VR samples taken 29.4 ms early, every published sample
    lies on the side of each power step it was measured on, and the energy equals the library's own
    (get_stats since start) — at nominal rates VR times would be a whole sample off within 0.7 s and
    the energy 1.35 % low."""
    fake_hdeem.control("run_external", 1)
    src = HdeemSource(**fake_hdeem.options(interval_s=0.0, method="global"))
    src.open()
    steps = []                                             # (wall ns before, after, new watts)
    parts = []
    for watts in (2.0, 3.5, 1.25, 4.0):
        fake_hdeem.advance(0.33)
        before = fake_hdeem.control("wall_ns")
        fake_hdeem.set_power(3, watts)                     # DDR_AB
        fake_hdeem.set_power(0, 100 * watts)               # BLADE
        steps.append((before, fake_hdeem.control("wall_ns"), watts))
        parts.append(src.poll())
    fake_hdeem.advance(0.33)
    fake_hdeem.control("run_external", 0)                  # the user stops: counts freeze
    parts.append(src.poll())
    for name, sensor, scale, period in (("DDR_AB", 3, 1.0, 1e12 / 98663), ("BLADE", 0, 100.0, 1e12 / 1003074)):
        t = np.concatenate([b.samples[name][0] for b in parts])
        p = np.concatenate([b.samples[name][1] for b in parts])
        assert np.all(np.diff(t) > 0)
        starts = t - period                                # a sample's value is the power at its start
        ambiguous = 0
        for (before, after, watts), nxt in zip(steps, [*steps[1:], (np.inf, np.inf, None)]):
            new = (starts >= after) & (starts < nxt[0])
            old = starts < before
            assert np.all(p[new] == scale * watts)
            assert not np.any(p[old & (starts >= steps[0][1])] == scale * watts) or watts in (2.0,)
            ambiguous += int(np.sum((starts >= before) & (starts < after)))
        assert ambiguous <= len(steps)
        reading = src.lib.stats(src._handle, False, 7)
        assert parts[-1].energy_j[name] == pytest.approx(reading.energy_j[sensor], rel=1e-6)
    src.close()


def test_samples_the_buffer_no_longer_holds_are_counted_as_gaps(fake_hdeem):
    """first_blade_value is the index of the first blade sample held: when the buffer dropped samples
    the source has not published, they are counted as missing, and later samples keep their times."""
    fake_hdeem.control("run_external", 1)
    src = HdeemSource(**fake_hdeem.options(interval_s=0.0, method="global"))
    src.open()
    fake_hdeem.advance(0.2)
    first = src.poll()
    fake_hdeem.control("blade_cap", 100)                   # the buffer keeps the last 100 blade samples
    fake_hdeem.advance(0.5)
    later = src.poll()
    src.close()
    t1, t2 = first.samples["BLADE"][0], later.samples["BLADE"][0]
    lost = later.gaps["BLADE"]
    assert len(t2) == 100 and later.status["BLADE"] == "gap" and 400 <= lost <= 800
    assert (t2[0] - t1[-1]) == pytest.approx((lost + 1) * 1e12 / 1003074, abs=2)


@pytest.mark.slow
def test_shim_builds_against_the_legacy_header_without_the_sets_it_breaks(fake_hdeem, tmp_path):
    """The old fake header (first_blade_value a timespec, int hdeem_close, no status times) still
    builds the energy path; the status-times and global sets are left out with the compiler's reason,
    and the global method says so instead of failing to build at all."""
    path = build_shim(include_dir=str(LEGACY), lib_dir=str(fake_hdeem.lib_dir), cache_dir=str(tmp_path))
    assert ShimLib(path).features == 0
    notes = shim_build_notes(path)
    assert "start_time_blade" in notes and "aggregate value used where an integer" in notes  # the timespec
    new = build_shim(**fake_hdeem.options())
    assert ShimLib(new).features == FEATURE_STATUS_TIMES | FEATURE_GLOBAL and shim_build_notes(new) == ""
    legacy_global = HdeemSource(include_dir=str(LEGACY), lib_dir=str(fake_hdeem.lib_dir), cache_dir=str(tmp_path),
                                method="global")
    with pytest.raises(SourceUnavailable, match="hdeem_method = 'energy'"):
        legacy_global.open()


@pytest.mark.slow
def test_site_library_named_so_1_is_found_and_linked(fake_hdeem, tmp_path):
    """A site that installs only libhdeem.so.1 (no development symlink) is found and linked (-l:)."""
    lib_dir = tmp_path / "lib"
    lib_dir.mkdir()
    (lib_dir / "libhdeem.so.1").symlink_to(fake_hdeem.lib_dir / "libhdeem.so")
    (lib_dir / "libfreeipmi.so").symlink_to(fake_hdeem.lib_dir / "libfreeipmi.so")
    src = HdeemSource(include_dir=str(fake_hdeem.include_dir), lib_dir=str(lib_dir), cache_dir=str(tmp_path / "c"),
                      interval_s=0.0)
    src.open()
    src.close()
    from hdeem_watch.sources.hdeem import probe

    assert probe(str(fake_hdeem.include_dir), str(lib_dir)) is None


def _daemon(tmp_path: Path, fake, extra_env: dict[str, str]) -> tuple[list[str], str]:
    """Run a real daemon process on the fake for ~2 s; return the libhdeem calls it made and the
    source health its status op reported."""
    from hdeem_watch.wire.client import ControlClient

    log = tmp_path / "calls.log"
    env = {**os.environ, "PYTHONPATH": str(SRC), "HDEEM_FAKE_LOG": str(log), "XDG_CACHE_HOME": str(tmp_path / "cache"),
           "HDEEM_WATCH_HDEEM_INCLUDE_DIR": str(fake.include_dir), "HDEEM_WATCH_HDEEM_LIB_DIR": str(fake.lib_dir),
           **extra_env}
    cmd = [sys.executable, "-m", "hdeem_watch", "daemon", "--source", "hdeem", "--pub", f"ipc://{tmp_path}/p.sock",
           "--control", f"ipc://{tmp_path}/c.sock", "--state-dir", str(tmp_path / "state"), "--node", "n1"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    # a subscriber watches, so the daemon polls at full rate (unwatched it reads HDEEM's buffer rarely)
    context = zmq.Context.instance()
    watcher = context.socket(zmq.SUB)
    watcher.setsockopt(zmq.SUBSCRIBE, b"")
    watcher.connect(f"ipc://{tmp_path}/p.sock")
    deadline = time.monotonic() + 60
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            if log.exists() and log.read_text().count("get_stats_total") >= 5:
                break
            time.sleep(0.1)
    finally:
        watcher.close(linger=0)
    health = ""
    if proc.poll() is None:
        with ControlClient(f"ipc://{tmp_path}/c.sock", timeout_s=10.0) as client:
            health = str(client.call("status")["source"]["health"])
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err.decode()[-2000:]
    return log.read_text().split(), health


@pytest.mark.slow
def test_the_passive_daemon_makes_no_ownership_call(fake_hdeem, tmp_path):
    """A real `hdeem-watch daemon --source hdeem` process: polls through get_stats_total, never calls
    hdeem_start/clear/stop, and its status says no measurement runs; with
    HDEEM_WATCH_HDEEM_OWN_MEASUREMENT=1 it starts and stops one."""
    (tmp_path / "a").mkdir()
    passive, health = _daemon(tmp_path / "a", fake_hdeem, {})
    assert passive.count("get_stats_total") >= 5 and passive[-1] == "close"
    assert not OWNERSHIP_CALLS & set(passive), passive
    assert "no HDEEM measurement running" in health
    (tmp_path / "b").mkdir()
    owning, health = _daemon(tmp_path / "b", fake_hdeem, {"HDEEM_WATCH_HDEEM_OWN_MEASUREMENT": "1"})
    assert "start" in owning and "stop" in owning and health == "ok"
