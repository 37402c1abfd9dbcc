"""Self-measurement of the UI for benchmarks: frames painted, CPU time, messages and gaps.

``hdeem-watch tui --stats FILE`` starts a :class:`StatsWriter` that appends one JSON line per
second: ``{"t_s", "frames", "cpu_s", "messages", "gaps"}`` (monotonic seconds, frames painted so
far, the process's user+system CPU seconds, stream messages received and missed so far). A
benchmark takes the differences over a steady window (``benchmarks/bench_tui.py``).
"""

from __future__ import annotations

import json
import os
import threading
import time
from collections.abc import Callable
from typing import TextIO

from hdeem_watch.tui.feed import FeedHub


class StatsWriter(threading.Thread):
    """Appends a stats line every ``period_s`` until stopped.

    Args:
        out: the JSON-lines file, opened for appending by the caller (so that a path that cannot be
            written is a one-line error before the UI starts); closed when the writer stops.
        frames: returns the frames painted so far.
        hub: the feeds (messages and gaps).
        period_s: seconds between lines.
    """

    def __init__(self, out: TextIO, frames: Callable[[], int], hub: FeedHub, period_s: float = 1.0) -> None:
        super().__init__(name="hdeem-watch-stats", daemon=True)
        self._out = out
        self._frames = frames
        self._hub = hub
        self._period_s = period_s
        self._halt = threading.Event()

    def line(self) -> dict[str, float]:
        """The current figures."""
        times = os.times()
        return {
            "t_s": time.monotonic(),
            "frames": self._frames(),
            "cpu_s": times.user + times.system,
            "messages": sum(feed.messages for feed in self._hub.feeds),
            "gaps": sum(feed.latest.health.gaps for feed in self._hub.feeds),
        }

    def run(self) -> None:
        with self._out as out:
            while not self._halt.wait(self._period_s):
                out.write(json.dumps(self.line()) + "\n")
                out.flush()

    def stop(self) -> None:
        """Stop writing."""
        self._halt.set()
        self.join(2.0)
