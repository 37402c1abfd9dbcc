"""Counters recorded beside a recording and played back with it (``counters = "replay"``, issue 17)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hdeem_watch.counters.event_tables import TABLES
from hdeem_watch.counters.source import CounterSnapshot, window_counts
from hdeem_watch.daemon.counters.record import (
    CounterRecorder,
    CounterReplay,
    counters_path,
    read_counter_recording,
)
from hdeem_watch.errors import InputError
from hdeem_watch.sources.replay import ReplaySource, write_recording

SECOND = 1_000_000_000
T0 = 1_700_000_000 * SECOND


def recorded(tmp_path: Path) -> Path:
    path = tmp_path / "r.csv"
    t = T0 + np.arange(1, 501) * 10_000_000  # 5 s of DDR_AB at 100 Sa/s
    write_recording(path, {"DDR_AB": (t, np.full(t.size, 4.0))})
    rec = CounterRecorder(counters_path(path), kind="sim", table=TABLES["haswell-ep"], ranks=2, channels=())
    for k in range(6):
        rec.write(CounterSnapshot(T0 + k * SECOND, {"S0.imc0": {"act": 1e6 * k, "cas_rd": float("nan")}},
                                  {"S0.imc0": {"cas_rd": 1}} if k >= 3 else {}))
    rec.close()
    return path


def test_replayed_counters_follow_the_replay_on_its_axis(tmp_path: Path) -> None:
    """At each read the counts are the recorded ones at the replay's position (interpolated), stamped
    like the played samples; NaN and unknown-poll tallies survive the round trip."""
    path = recorded(tmp_path)
    now = [0]
    source = ReplaySource(path, speed=2.0, clock=lambda: now[0], wall_clock=lambda: 42 * SECOND)
    source.open()
    replay = CounterReplay(path, source)
    assert replay.table.generation == "haswell-ep" and replay.ranks == 2
    now[0] = SECOND // 2
    batch = source.poll()
    first = replay.read()
    assert first.t_ns == 42 * SECOND + SECOND  # one recorded second after the first sample, played axis
    assert 0 < first.t_ns - int(batch.samples["DDR_AB"][0][-1]) <= 10_000_000  # where the samples are
    assert first.counts["S0.imc0"]["act"] == pytest.approx(1.01e6)  # recorded T0 + 1.01 s
    now[0] = 2 * SECOND
    source.poll()
    last = replay.read()
    assert last.counts["S0.imc0"]["act"] == pytest.approx(4.01e6)
    window = window_counts(first, last)["S0.imc0"]
    assert window["act"] == pytest.approx(3e6) and np.isnan(window["cas_rd"])


def test_bad_counter_recordings_are_one_line_errors(tmp_path: Path) -> None:
    path = recorded(tmp_path)
    lines = counters_path(path).read_text().splitlines()
    counters_path(path).write_text("\n".join([lines[0], lines[2], lines[1]]) + "\n")
    with pytest.raises(InputError, match=r"r.csv.counters.jsonl:3: t_ns"):
        read_counter_recording(counters_path(path))
    counters_path(path).write_text('{"format": "other"}\n')
    with pytest.raises(InputError, match="header"):
        read_counter_recording(counters_path(path))
    with pytest.raises(InputError, match="looping"):
        CounterReplay(path, ReplaySource(path, loop=True))
