"""The daemon records what it streams, and a daemon with the replay source (on TCP) plays the recording back.

The recorder is stopped with SIGTERM, which also checks the clean shutdown (exit 0, sockets removed).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hdeem_watch.sources.replay import read_recording
from hdeem_watch.wire import protocol


@pytest.mark.slow
def test_record_then_replay(daemon_factory: Any, receive: Any) -> None:
    """--record writes every streamed sample; --source replay streams the same values at their rates."""
    recorder = daemon_factory("--speed", "10", name="rec")
    path = recorder.directory / "rec.csv"
    recorder.args += ["--record", str(path)]
    recorder.start()
    sub = recorder.subscriber(protocol.subscription(recorder.node, "samples") + b"DDR_AB")
    streamed = receive(sub, 5.0, until=lambda m: len(m) >= 10)
    sub.close()
    time.sleep(0.2)
    assert recorder.terminate() == 0, recorder.stderr()  # SIGTERM: a clean stop, files flushed and closed
    assert "Traceback" not in recorder.stderr()
    assert not Path(recorder.pub[6:]).exists() and not Path(recorder.control[6:]).exists()
    recording = read_recording(path)
    t_rec, p_rec = recording.channels["DDR_AB"]
    t_live = np.concatenate([m.samples()[0] for m in streamed])
    p_live = np.concatenate([m.samples()[1] for m in streamed])
    first = int(np.searchsorted(t_rec, t_live[0]))
    assert np.array_equal(t_rec[first:first + t_live.size], t_live)
    assert np.array_equal(p_rec[first:first + p_live.size], p_live)

    # The player listens on loopback TCP: remote subscribers connect the same way.
    player = daemon_factory("--source", "replay", "--replay-file", str(path), "--speed", "4", name="play",
                            tcp=True).start()
    assert player.pub.startswith("tcp://")
    sub = player.subscriber(protocol.subscription(player.node, "samples") + b"DDR_AB")
    replayed = receive(sub, 5.0, until=lambda m: sum(b.samples()[1].size for b in m) > 60)
    sub.close()
    values = np.concatenate([m.samples()[1] for m in replayed])
    times = np.concatenate([m.samples()[0] for m in replayed])
    assert values.size > 50 and np.all(np.diff(times) == 10_000_000)
    matches = [s for s in range(p_rec.size - values.size) if np.array_equal(p_rec[s:s + values.size], values)]
    assert matches, "the replayed values are not a stretch of the recording"
