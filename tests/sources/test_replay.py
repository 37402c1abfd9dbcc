"""The replay source and the recording format: round trip, playback speed, looping, malformed input."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from hdeem_watch.errors import InputError
from hdeem_watch.sources.registry import make_source
from hdeem_watch.sources.replay import RecordingWriter, ReplaySource, read_recording, write_recording
from hdeem_watch.sources.sim import SimSource

S = 1_000_000_000


def sim_recording(path: Path, clock, seconds: float = 2.0) -> dict:
    """Record a sim for `seconds` of the fake `clock` in irregular polls; returns the samples per channel."""
    sim = SimSource(seed=11, clock=clock, wall_clock=lambda: 1_600_000_000 * S)
    sim.open()
    writer = RecordingWriter(path, node="sim", rate_hz={c.name: c.rate_hz for c in sim.channels()})
    got: dict[str, list] = {}
    while clock.t < seconds * S:
        clock.t += 37_000_000
        batch = sim.poll()
        writer.write_batch(batch)
        for ch, (t, p) in batch.samples.items():
            got.setdefault(ch, []).append((t, p))
    writer.close()
    return {ch: (np.concatenate([t for t, _ in v]), np.concatenate([p for _, p in v])) for ch, v in got.items()}


def test_round_trip_of_a_sim_recording(tmp_path, fake_clock):
    """What the writer records from a live source reads back identically, with rates from the metadata."""
    path = tmp_path / "rec.csv"
    samples = sim_recording(path, fake_clock())
    rec = read_recording(path)
    assert rec.meta["node"] == "sim" and rec.rate_hz["BLADE"] == 1000.0
    for ch, (t, p) in samples.items():
        assert np.array_equal(rec.channels[ch][0], t)
        assert np.array_equal(rec.channels[ch][1], p)


def test_playback_at_recorded_speed_returns_each_sample_once(tmp_path, fake_clock):
    """Polled at any pace, playback yields every recorded sample exactly once, when its time has come."""
    path = tmp_path / "rec.csv"
    samples = sim_recording(path, fake_clock(), seconds=1.0)
    clock = fake_clock()
    src = ReplaySource(path, clock=clock, wall_clock=lambda: 5 * S)
    src.open()
    clock.t = S // 2
    half = src.poll()
    n_half = len(half.samples["DDR_AB"][0])
    assert 49 <= n_half <= 51
    parts = [half]
    for _ in range(30):
        clock.t += 23_000_000
        parts.append(src.poll())
    blade = np.concatenate([b.samples["BLADE"][1] for b in parts])
    assert np.array_equal(blade, samples["BLADE"][1])
    t = np.concatenate([b.samples["BLADE"][0] for b in parts])
    assert np.all(np.diff(t) == 1_000_000) and t[0] == 5 * S   # restamped from the open
    assert src.health() == "ended"
    assert parts[-1].energy_j["DDR_AB"] == pytest.approx(samples["DDR_AB"][1].sum() * 0.01)


def test_faster_and_looping(tmp_path, fake_clock):
    """At speed 4 one clock second plays four recorded seconds; with loop the recording repeats seamlessly."""
    path = tmp_path / "r.csv"
    t = np.arange(1, 101, dtype=np.int64) * 10_000_000 + 7 * S     # 1 s at 100 Sa/s
    write_recording(path, {"DDR_CD": (t, np.linspace(1.0, 2.0, 100))})
    clock = fake_clock()
    src = make_source("replay", path=path, speed=4.0, loop=True, clock=clock, wall_clock=lambda: 0)
    src.open()
    clock.t = S
    batch = src.poll()
    times, values = batch.samples["DDR_CD"]
    assert len(times) == 400
    assert np.all(np.diff(times) == 10_000_000)                    # no seam at the loop boundary
    assert np.array_equal(values[:100], values[300:])
    assert src.health() == "ok"


def test_original_timestamps_without_restamp(tmp_path, fake_clock):
    """restamp=False publishes the recorded wall-clock timestamps (post-mortem analysis)."""
    path = tmp_path / "r.csv"
    t = np.array([100, 200, 300], dtype=np.int64) * 1_000_000
    write_recording(path, {"CPU0": (t, np.array([10.0, np.nan, 12.0]))})
    clock = fake_clock()
    src = ReplaySource(path, restamp=False, clock=clock)
    src.open()
    clock.t = S
    batch = src.poll()
    assert np.array_equal(batch.samples["CPU0"][0], t)
    assert batch.status["CPU0"] == "stale"           # an unknown (NaN) sample is flagged
    assert batch.gaps == {"CPU0": 1}                 # ... and counted missing (issue 22.10), not 0 W
    assert batch.energy_j["CPU0"] == pytest.approx(22.0 * 0.1)


@pytest.mark.parametrize(("text", "line", "what"), [
    ("# hdeem-watch recording v2\nt_ns,channel,power_w\n1,BLADE,1\n", 1, "version"),
    ("t_ns,channel,power_w\n1,BLADE,1\n", 1, "expected"),
    ("# hdeem-watch recording v1\ntime,ch,p\n", 2, "header"),
    ("# hdeem-watch recording v1\nt_ns,channel,power_w\n1,BLADE,1\n2,BLADE\n", 4, "3 fields"),
    ("# hdeem-watch recording v1\nt_ns,channel,power_w\n1.5,BLADE,1\n", 3, "integer"),
    ("# hdeem-watch recording v1\nt_ns,channel,power_w\n1,BLADE,watt\n", 3, "not a number"),
    ("# hdeem-watch recording v1\nt_ns,channel,power_w\n5,BLADE,1\n5,BLADE,1\n", 4, "does not increase"),
    # issue 22.10: accepted or tracebacks before
    ("# hdeem-watch recording v1\nt_ns,channel,power_w\n1,BLADE,1e300\n", 3, "power_w 1e.300 is implausible"),
    ("# hdeem-watch recording v1\nt_ns,channel,power_w\n1,BLADE,inf\n", 3, "power_w 'inf' is not finite"),
    ("# hdeem-watch recording v1\nt_ns,channel,power_w\n1,BLADE,-Infinity\n", 3, "not finite"),
    ("# hdeem-watch recording v1\nt_ns,channel,power_w\n18446744073709551616,BLADE,1\n", 3,
     "t_ns 18446744073709551616 is out of range"),
    ("# hdeem-watch recording v1\nt_ns,channel,power_w\n-5,BLADE,1\n", 3, "t_ns -5 is out of range"),
    ("# hdeem-watch recording v1\nt_ns,channel,power_w\n1,DDR/AB,1\n", 3, "channel 'DDR/AB' is not a valid name"),
])
def test_malformed_recording_names_the_line(tmp_path, text, line, what):
    """Each malformed recording is an InputError naming the file, the line and what was wrong."""
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(InputError, match=f"bad.csv:{line}: .*{what}"):
        ReplaySource(path)


@pytest.mark.parametrize("rate", ["-100", "0", "nan", "inf"])
def test_bad_rate_metadata_names_the_value(tmp_path, rate):
    """rate_hz negative (energies and baselines of the wrong sign), 0 or NaN (tracebacks before): one
    InputError naming the file, the field and the value."""
    path = tmp_path / "r.csv"
    path.write_text(f"# hdeem-watch recording v1\n# rate_hz: BLADE={rate}\nt_ns,channel,power_w\n1,BLADE,1\n2,BLADE,1\n")
    with pytest.raises(InputError, match=rf"r.csv: metadata rate_hz 'BLADE={re.escape(rate)}'.*finite number > 0"):
        ReplaySource(path)


@pytest.mark.slow
def test_daemon_with_a_bad_recording_exits_2_with_one_line(tmp_path):
    """`hdeem-watch daemon --source replay` on a recording with t_ns = 2**64: exit 2, one line naming
    file, line and value, no traceback."""
    import os
    import subprocess
    import sys

    path = tmp_path / "bad.csv"
    path.write_text("# hdeem-watch recording v1\nt_ns,channel,power_w\n18446744073709551616,DDR_AB,1\n")
    src = Path(__file__).resolve().parents[2] / "src"
    proc = subprocess.run([sys.executable, "-m", "hdeem_watch", "daemon", "--source", "replay", "--replay-file",
                           str(path), "--pub", f"ipc://{tmp_path}/p.sock", "--control", f"ipc://{tmp_path}/c.sock",
                           "--state-dir", str(tmp_path / "state")], capture_output=True, text=True, timeout=60,
                          env={**os.environ, "PYTHONPATH": str(src)})
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert "bad.csv:3: t_ns 18446744073709551616 is out of range" in proc.stderr


def test_an_all_nan_channel_has_an_unknown_energy_not_zero(tmp_path, fake_clock):
    """Issue 28: a recording whose DDR_AB samples are all unknown reported energy_j 0.0 for it; the
    energy is NaN (null on the wire) until a known sample arrives, and the other channels' energies
    stay exact."""
    t = np.arange(100, dtype=np.int64) * 10_000_000 + S
    path = tmp_path / "nan.csv"
    write_recording(path, {"DDR_AB": (t, np.full(100, np.nan)), "DDR_CD": (t, np.full(100, 2.0))},
                    node="n", rate_hz={"DDR_AB": 100.0, "DDR_CD": 100.0})
    clock = fake_clock()
    src = ReplaySource(path, clock=clock)
    src.open()
    clock.t = 2 * S
    batch = src.poll()
    assert np.isnan(batch.energy_j["DDR_AB"]) and batch.gaps["DDR_AB"] == 100
    assert batch.energy_j["DDR_CD"] == pytest.approx(2.0)


def test_replay_loop_is_a_flag_like_every_setting() -> None:
    """Issue 28: sources.md says every key has a flag; replay_loop had none."""
    from hdeem_watch.config import load_settings

    settings = load_settings(None, env={}, overrides={"source": "replay", "replay_file": "x.csv", "replay_loop": True})
    assert settings.source_options()["loop"] is True
    from hdeem_watch.cli import build_parser

    args = build_parser("daemon").parse_args(["daemon", "--source", "replay", "--replay-file", "x.csv",
                                              "--replay-loop"])
    assert args.replay_loop is True


def test_a_replay_daemon_does_not_blame_a_missing_sysfs(fake_clock) -> None:
    """Issue 28: the replay daemon logged "no devices/system/cpu/cpu*/topology (not Linux…)" although
    it never looks at this host: its node is described by the [node] table alone."""
    from hdeem_watch.node.setup import configured_only, node_setup

    why = "a replayed recording: describe its node in the [node] table"
    setup = node_setup(configured_only(why), None, memspec_setting=None)
    assert "devices/system/cpu" not in setup.topology_note and why in setup.topology_note


def test_the_example_recording_is_long_enough_to_watch() -> None:
    """Issue 28: the documented example was one second (over in 50 ms at --speed 20); the example
    to watch is 50 s of runs whose DRAM power steps well above idle."""
    recording = read_recording(Path(__file__).resolve().parents[2] / "examples" / "recording-runs.csv")
    t, p = recording.channels["DDR_AB"]
    assert (t[-1] - t[0]) / S >= 30 and sorted(recording.channels) == ["DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH"]
    assert np.nanmax(p) > 10 * np.nanmin(p) > 0
