"""The HDEEM source on a fake libhdeem written in C: shim build, ΔE/Δt, and every documented quirk.

The fake (fake_hdeem/hdeem.h, libhdeem.c) follows what public code compiled against the real header
shows: void hdeem_close and an integer first_blade_value (tud-zih-energy/phdeem src/phdeem.c,
src/example/testPhdeem.c), status start/stop times with periods measured as duration / samples and
VR samples shifted by -(35000 - 5600) us (score-p/scorep_plugin_hdeem hdeem_plugin.cpp), totals
since power-on needing no measurement (tud-zih-energy/hdeem_cxx include/hdeem_cxx.hpp,
tud-zih-energy/metricq-source-hdeem src/hdeem_connection.cpp), real rates 1003.07 / 98.66 Sa/s
(Taurus capture tests/data/taurus/6415.txt).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from hdeem_watch.sources.base import CHANNELS, SourceUnavailable
from hdeem_watch.sources.hdeem import HdeemSource
from hdeem_watch.sources.hdeem_lib import BMC_POLLING, VR_OVERFLOW, HdeemError, ShimLib, build_shim
from hdeem_watch.sources.registry import available_sources, make_source


def opened(fake, **kw) -> HdeemSource:
    kw.setdefault("interval_s", 0.0)
    src = HdeemSource(**fake.options(**kw))
    src.open()
    return src


@pytest.mark.slow
def test_shim_builds_once_and_reads_names(fake_hdeem):
    """The shim compiles against hdeem.h with the documented link line, is cached, and reads the sensors."""
    path = build_shim(**fake_hdeem.options(libs=("hdeem", "freeipmi", "rt")))
    again = build_shim(**fake_hdeem.options(libs=("hdeem", "freeipmi", "rt")))
    assert path == again and path.stat().st_size > 0
    lib = ShimLib(path)
    handle = lib.open()
    try:
        assert lib.sensor_names(handle) == list(CHANNELS)
        assert lib.sensor_count(handle) == (1, 6)
    finally:
        lib.close(handle)


def test_a_failed_init_is_closed(fake_hdeem):
    """After hdeem_init fails the shim calls hdeem_close before freeing the handle, as hdeem_cxx's
    connection::init does since commit 5b77f10 ("we might be leaking FDs if we don't close")."""
    lib = ShimLib(build_shim(**fake_hdeem.options(libs=("hdeem", "freeipmi", "rt"))))
    fake_hdeem.control("log_reset")
    fake_hdeem.control("fail_init", 1)
    with pytest.raises(HdeemError, match="hdeem_init"):
        lib.open()
    assert fake_hdeem.calls() == ["init", "close"]
    handle = lib.open()                 # the next init succeeds and is closed once, by the caller
    lib.close(handle)
    assert fake_hdeem.calls() == ["init", "close", "init", "close"]


def test_missing_header_is_unavailable(tmp_path):
    """No hdeem.h → SourceUnavailable naming it; available_sources reports why."""
    with pytest.raises(SourceUnavailable, match=r"hdeem\.h not found") as info:
        make_source("hdeem", include_dir=str(tmp_path), lib_dir=str(tmp_path), cache_dir=str(tmp_path)).open()
    # issue 20: the message names the key and its environment variable, not a bare "include_dir option"
    assert "hdeem_include_dir" in info.value.reason and "HDEEM_WATCH_HDEEM_INCLUDE_DIR" in info.value.reason
    reason = available_sources(hdeem_include_dir=str(tmp_path))["hdeem"]
    assert reason and "hdeem.h" in reason and "HDEEM_WATCH_HDEEM_INCLUDE_DIR" in reason


def test_energy_method_publishes_delta_e_over_delta_t(fake_hdeem):
    """Each poll publishes ΔE/Δt between the BMC's read times; the sum of sample energies equals the totals."""
    src = opened(fake_hdeem)
    try:
        fake_hdeem.set_power(3, 2.5)       # DDR_AB
        fake_hdeem.set_power(0, 150.0)     # BLADE
        fake_hdeem.advance(1.0)
        b1 = src.poll()
        fake_hdeem.set_power(3, 4.0)
        fake_hdeem.advance(2.0)
        b2 = src.poll()
        t1, p1 = b1.samples["DDR_AB"]
        t2, p2 = b2.samples["DDR_AB"]
        assert len(p1) == 1 and len(p2) == 1
        assert p2[0] == pytest.approx(4.0, abs=0.05)   # a few 2.5 W samples if the machine stalls
        assert b2.samples["BLADE"][1][0] == pytest.approx(150.0, abs=0.2)
        dt = (t2[0] - t1[0]) * 1e-9
        assert 1.99 <= dt <= 2.3                       # the fake's clock also runs in real time
        # no energy lost between polls: cumulative energy = Σ P·Δt of the published samples (+ first interval)
        assert b2.energy_j["DDR_AB"] - b1.energy_j["DDR_AB"] == pytest.approx(p2[0] * dt, rel=1e-9)
        assert all(s == "ok" for s in b2.status.values())
    finally:
        src.close()


def test_start_while_running_clears_then_starts(fake_hdeem):
    """Owning mode: a measurement left running makes hdeem_start fail; the source clears and starts again."""
    path = build_shim(**fake_hdeem.options(libs=("hdeem", "freeipmi", "rt")))
    lib = ShimLib(path)
    handle = lib.open()
    lib.clear(handle)
    assert lib.start(handle) == 0
    assert lib.start(handle) != 0          # the quirk itself
    lib.stop(handle)
    fake_hdeem.control("run_external", 1)  # somebody else's measurement runs
    lib.close(handle)
    fake_hdeem.control("log_reset")
    src = opened(fake_hdeem, own_measurement=True)
    src._status = src.lib.status(src._handle)
    src._start()                           # taking over: start fails, so clear, then start
    try:
        assert fake_hdeem.calls()[-4:] == ["start", "clear", "start", "check_status"]
        assert fake_hdeem.control("running") == 1
        assert src.health() == "ok"
    finally:
        src.close()


def test_stop_is_asynchronous_and_overflow_is_read_after(fake_hdeem):
    """Owning mode: close() waits until the status stops polling, then reads the overflow flags."""
    src = opened(fake_hdeem, own_measurement=True)
    fake_hdeem.control("stop_ms", 150)
    fake_hdeem.control("overflow", 4)      # the fake's VR overflow bit
    flags = src.stop()
    assert flags & VR_OVERFLOW
    assert not src.lib.status(src._handle).flags & BMC_POLLING
    src.close()


def test_slow_get_stats_is_missing_data_without_energy_loss(fake_hdeem):
    """A get_stats slower than slow_s gives NaN + 'stale'; the next good poll covers the interval."""
    src = opened(fake_hdeem, slow_s=0.2)
    try:
        fake_hdeem.set_power(4, 3.0)       # DDR_CD
        fake_hdeem.advance(1.0)
        good = src.poll()
        fake_hdeem.control("slow_ms", 400)
        fake_hdeem.control("slow_calls", 1)
        fake_hdeem.advance(1.0)
        slow = src.poll()
        assert math.isnan(slow.samples["DDR_CD"][1][0]) and slow.status["DDR_CD"] == "stale"
        fake_hdeem.advance(1.0)
        after = src.poll()
        t_good, t_after = good.samples["DDR_CD"][0][0], after.samples["DDR_CD"][0][0]
        assert 2.39 <= (t_after - t_good) * 1e-9 <= 2.7   # one sample over both intervals (+0.4 s slow call)
        assert after.samples["DDR_CD"][1][0] == pytest.approx(3.0, abs=0.02)
        assert after.energy_j["DDR_CD"] - good.energy_j["DDR_CD"] == pytest.approx(
            3.0 * (t_after - t_good) * 1e-9, rel=0.01)
    finally:
        src.close()


def test_connection_loss_reconnects_with_backoff(fake_hdeem, fake_clock):
    """A failing BMC gives NaN + 'error: ...'; reconnects follow an exponential back-off; energy continues."""
    clock = fake_clock()
    src = opened(fake_hdeem, clock=clock, backoff_s=0.5, backoff_max_s=4.0)
    try:
        fake_hdeem.set_power(5, 2.0)        # DDR_EF
        fake_hdeem.advance(1.0)
        before = src.poll()
        fake_hdeem.control("fail_calls", 1)
        fake_hdeem.control("fail_init", 2)
        failed = src.poll()
        assert failed.status["DDR_EF"].startswith("error:") and math.isnan(failed.samples["DDR_EF"][1][0])
        assert src.health().startswith("error")
        attempts = []
        recovered = False
        for _ in range(40):                       # 0.1 s steps of the injected clock
            clock.t += 100_000_000
            n = src.reconnects
            batch = src.poll()
            if src.reconnects > n:
                attempts.append(clock.t)
            if batch.status["DDR_EF"] == "ok":
                recovered = True
                break
        gaps = np.diff([0, *attempts]) / 1e9
        assert len(attempts) == 3                     # two failed inits, then success
        assert gaps[0] == pytest.approx(0.5, abs=0.11)
        assert gaps[1] == pytest.approx(1.0, abs=0.11) and gaps[2] == pytest.approx(2.0, abs=0.11)
        assert recovered and src.health().startswith("ok")
        fake_hdeem.advance(1.0)
        after = src.poll()
        # the first good reading after the outage covers it: energy since open keeps growing at 2 W
        total_s = (after.samples["DDR_EF"][0][0] - before.samples["DDR_EF"][0][0]) * 1e-9
        assert after.energy_j["DDR_EF"] - before.energy_j["DDR_EF"] == pytest.approx(2.0 * total_s, rel=0.01)
    finally:
        src.close()


@pytest.mark.parametrize("style", [1, 2])
def test_sensor_names_are_normalised(fake_hdeem, style):
    """'ddr ab' and 'Ddr_Ab' spellings map onto the canonical channel names."""
    fake_hdeem.control("names_style", style)
    src = opened(fake_hdeem)
    try:
        assert [c.name for c in src.channels()] == list(CHANNELS)
        assert {c.kind for c in src.channels()} == {"blade", "cpu", "dram"}
    finally:
        src.close()


def test_permission_denied_names_the_fix(fake_hdeem):
    """hdeem_init failing with EACCES → SourceUnavailable telling to run as the privileged collector."""
    fake_hdeem.control("deny", 1)
    with pytest.raises(SourceUnavailable, match="privileged collector"):
        opened(fake_hdeem)


def test_global_method_measured_rates(fake_hdeem):
    """The global readout gives BLADE and VR samples at the measured rates (1003.07 / 98.66 Sa/s, not
    the nominal 1000 / 100) in 0.125 W steps, each sample once."""
    fake_hdeem.control("run_external", 1)          # a user's measurement (e.g. Score-P) runs
    fake_hdeem.advance(0.1)
    src = opened(fake_hdeem, method="global")
    try:
        assert src.channels()[0].rate_hz == pytest.approx(1003.074)   # measured at open already
        fake_hdeem.set_power(6, 1.3)          # quantised to 1.25
        fake_hdeem.advance(0.5)
        batch = src.poll()
        nb, nv = len(batch.samples["BLADE"][0]), len(batch.samples["DDR_GH"][0])
        # the fake's clock also runs in real time: allow for a loaded machine (up to 0.25 s late)
        assert 499 <= nb <= 760 and 49 <= nv <= 75
        assert src.periods_ns == (pytest.approx(1e12 / 1003074), pytest.approx(1e12 / 98663))
        assert np.all(np.abs(np.diff(batch.samples["BLADE"][0]) - 1e12 / 1003074) <= 1)
        assert np.all(np.abs(np.diff(batch.samples["CPU0"][0]) - 1e12 / 98663) <= 1)
        assert [c.rate_hz for c in src.channels()][:2] == [pytest.approx(1003.074), pytest.approx(98.663)]
        values = batch.samples["DDR_GH"][1]
        assert np.allclose(values / 0.125, np.round(values / 0.125))
        assert values[-1] == 1.25
        fake_hdeem.advance(0.2)
        nxt = src.poll()
        gap = nxt.samples["DDR_GH"][0][0] - batch.samples["DDR_GH"][0][-1]
        assert abs(gap - 1e12 / 98663) <= 2                        # no repeats, no holes
    finally:
        src.close()


def test_overflow_flags_while_polling_mark_the_group(fake_hdeem, fake_clock):
    """A VR overflow flag read during polling marks the VR channels 'overflow', not the blade."""
    clock = fake_clock()
    src = opened(fake_hdeem, clock=clock, status_every_s=1.0)
    try:
        fake_hdeem.control("overflow", 4)      # the fake's VR overflow bit
        clock.t += 2_000_000_000
        fake_hdeem.advance(0.5)
        batch = src.poll()
        assert batch.status["DDR_AB"] == "overflow" and batch.status["CPU1"] == "overflow"
        assert batch.status["BLADE"] == "ok"
        assert src.health().startswith("overflow")
    finally:
        fake_hdeem.control("overflow", 0)
        src.close()


def test_global_rearm_drains_then_restarts(fake_hdeem, fake_clock):
    """Owning mode: re-arming the global buffer drains it, clears, starts again and reports the samples missed."""
    clock = fake_clock()
    src = opened(fake_hdeem, method="global", rearm_s=1.0, clock=clock, own_measurement=True)
    try:
        fake_hdeem.advance(0.3)
        first = src.poll()
        clock.t += 1_500_000_000
        fake_hdeem.advance(0.3)
        rearmed = src.poll()
        assert rearmed.status["DDR_AB"] == "gap" and rearmed.gaps["BLADE"] >= 1
        t_first, t_re = first.samples["BLADE"][0], rearmed.samples["BLADE"][0]
        assert 299 <= len(t_re) <= 550 and abs(t_re[0] - t_first[-1] - 1e12 / 1003074) <= 2
        fake_hdeem.advance(0.2)
        after = src.poll()
        assert 199 <= len(after.samples["BLADE"][0]) <= 450
        assert after.samples["BLADE"][0][0] > t_re[-1]          # a fresh buffer, later times
    finally:
        src.close()


def test_bmc_is_read_at_most_every_interval(fake_hdeem, fake_clock):
    """Polled faster than interval_s, the source reads the BMC once per interval; the rest are empty."""
    clock = fake_clock()
    src = opened(fake_hdeem, clock=clock, interval_s=0.5)
    try:
        counts = []
        for _ in range(10):
            clock.t += 100_000_000
            fake_hdeem.advance(0.1)
            counts.append(len(src.poll().samples["DDR_AB"][0]))
        assert counts == [1, 0, 0, 0, 0, 1, 0, 0, 0, 0]
        assert src.channels()[3].rate_hz == 2.0
    finally:
        src.close()


DRIVER = r"""
#include <stdio.h>
void *hws_open(const char *, const char *, const char *, int *);
void hws_close(void *);
int hws_sensor_count(void *, int *, int *);
int hws_sensor_name(void *, int, char *, int);
int hws_start(void *); int hws_stop(void *); int hws_clear(void *);
int hws_status(void *, int *, long long *, long long *);
int hws_stats(void *, int, int, double *, double *, double *, double *, double *, long long *, long long *);
int hws_global_fetch(void *, long long *, long long *);
long long hws_global_copy(void *, int, long long, long long, double *);
long long hdeem_fake_control(const char *, long long);
int main(void) {
    int err = 0, nb = 0, nv = 0, flags = 0;
    char name[64];
    double e[7], a[7], mx[7], mn[7], in[7], out[400];
    long long counts[2], read[2], first, t0, t1;
    for (int round = 0; round < 3; round++) {
        void *h = hws_open(NULL, NULL, NULL, &err);
        if (!h) return 10;
        hws_sensor_count(h, &nb, &nv);
        for (int i = 0; i < nb + nv; i++) hws_sensor_name(h, i, name, sizeof name);
        hws_clear(h);
        if (hws_start(h)) return 11;
        hdeem_fake_control("advance_ns", 300000000LL);
        if (hws_stats(h, 0, 7, e, a, mx, mn, in, counts, read)) return 12;
        if (hws_stats(h, 1, 7, e, a, mx, mn, in, counts, read)) return 13;
        for (int k = 0; k < 2; k++) {
            if (hws_global_fetch(h, counts, &first)) return 14;
            if (hws_global_copy(h, 0, 0, 300, out) < 290 || first != 1) return 15;
            if (hws_global_copy(h, 3, 0, 400, out) != counts[1]) return 16;
        }
        hws_stop(h);
        hws_status(h, &flags, &t0, &t1);
        hws_close(h);
    }
    printf("ok %d %d\n", nb, nv);
    return 0;
}
"""


@pytest.mark.slow
def test_shim_has_no_memory_errors_or_leaks(fake_hdeem, tmp_path):
    """The shim's C (open/names/stats/global/close, three rounds) runs clean under valgrind."""
    import shutil
    import subprocess

    shim = build_shim(**fake_hdeem.options(libs=("hdeem", "freeipmi", "rt")))
    (tmp_path / "driver.c").write_text(DRIVER)
    exe = tmp_path / "driver"
    cc = shutil.which("gcc") or shutil.which("cc")
    subprocess.run([cc, "-O1", "-g", "-o", str(exe), str(tmp_path / "driver.c"), str(shim),
                    f"-L{fake_hdeem.lib_dir}", "-lhdeem", f"-Wl,-rpath,{fake_hdeem.lib_dir}:{shim.parent}"],
                   check=True, capture_output=True)
    cmd = [str(exe)]
    if shutil.which("valgrind"):
        cmd = ["valgrind", "-q", "--leak-check=full", "--errors-for-leak-kinds=definite,indirect",
               "--error-exitcode=99", *cmd]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == "ok 1 6"


@pytest.mark.slow
def test_failures_from_the_environment_in_a_real_process(fake_hdeem):
    """In a separate process, HDEEM_FAKE_NAMES_STYLE / HDEEM_FAKE_DENY set the fake's behaviour."""
    import os
    import subprocess
    import sys

    script = (
        "import json, sys\n"
        "from hdeem_watch.sources.base import SourceUnavailable\nfrom hdeem_watch.sources.registry import make_source\n"
        f"opts = {fake_hdeem.options(interval_s=0.0)!r}\n"
        "src = make_source('hdeem', **opts)\n"
        "try:\n"
        "    src.open()\n"
        "except SourceUnavailable as exc:\n"
        "    print(json.dumps({'unavailable': exc.reason})); sys.exit(0)\n"
        "print(json.dumps({'channels': [c.name for c in src.channels()]})); src.close()\n"
    )
    out = {}
    for name, env in (("styled", {"HDEEM_FAKE_NAMES_STYLE": "1"}), ("denied", {"HDEEM_FAKE_DENY": "1"})):
        proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60,
                              env={**os.environ, **env})
        assert proc.returncode == 0, proc.stderr
        out[name] = proc.stdout
    assert '"channels": ["BLADE", "CPU0", "CPU1", "DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH"]' in out["styled"]
    assert "privileged collector" in out["denied"]


@pytest.mark.slow
def test_shim_sets_inband_access_fields(fake_hdeem):
    """In-band init needs hasGPIO/hasPCIe set (the fake refuses otherwise); the shim sets them by default."""
    src = opened(fake_hdeem)
    src.close()
    bare = HdeemSource(**fake_hdeem.options(cflags=("-DHWS_NO_GPIO_FIELDS",)))
    with pytest.raises(SourceUnavailable, match="code -22"):
        bare.open()
