"""Issue 31: the quiet-period search runs once per half history of new samples, and still sees every window.

A search reads every kept sample of every DRAM channel (9 ms a search on the simulated node, once
per re-publication it was 0.09 % of a core); a window of ``quiet_window_s`` stays in the
``quiet_history_s`` of kept samples for the history minus the window, so a search every half
history finds each quiet window at least once. Run on the pure run book with a recording store.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from hdeem_watch.daemon.book.state import NodeState
from hdeem_watch.daemon.ops.reporting import Identity, Reporter
from hdeem_watch.sources.base import ChannelInfo, SourceBatch

PERIOD_NS = 10_000_000  # 100 Sa/s
HISTORY_S, WINDOW_S = 60.0, 5.0


class RecordingStore:
    """The store worker's write port: keeps what would be written."""

    def __init__(self) -> None:
        self.writes: list[str] = []

    def write(self, label: str, action: Any) -> None:
        self.writes.append(label)

    def health(self) -> str:
        return "ok"


class Silent:
    """A publisher that publishes nothing (the test reads the book and the store)."""

    def publish(self, kind: str, body: Any, **_: Any) -> bool:
        return True


def feed(book: NodeState, k0: int, seconds: float, power_w: float, rng: np.random.Generator) -> int:
    """``seconds`` of samples at ``power_w`` (0.05 W noise: quiet) from sample ``k0``; the next k."""
    ks = np.arange(k0, k0 + round(seconds * 1e9 / PERIOD_NS), dtype=np.int64)
    for chunk in np.array_split(ks, max(1, len(ks) // 4)):
        p = power_w + rng.normal(0.0, 0.05, len(chunk))
        t = chunk * PERIOD_NS
        book.on_batch(SourceBatch(int(t[-1]), int(t[-1]), {"DDR_AB": (t, p)}, {"DDR_AB": 0.0}, {"DDR_AB": "ok"}))
    return int(ks[-1]) + 1


def test_the_search_runs_once_per_half_history_and_finds_every_quiet_level() -> None:
    book = NodeState([ChannelInfo("DDR_AB", 100.0, "dram")], node="n1", monotonic=lambda: 0, wall=lambda: 0,
                     history_s=HISTORY_S)
    store = RecordingStore()
    reporter = Reporter(book, calibration=None, source=None, publisher=Silent(), store=store,  # type: ignore[arg-type]
                        identity=Identity("fake", {}), poll_interval_ns=lambda: PERIOD_NS, clock=lambda: 0)
    rng = np.random.default_rng(3)

    def search() -> None:
        reporter.look_for_quiet_periods(window_s=WINDOW_S, max_spread_w=0.5, history_s=HISTORY_S)

    k = feed(book, 1, 10.0, 4.0, rng)
    search()                                    # the first search: a quiet level at 4 W
    assert book.baselines["DDR_AB"].power_w == pytest.approx(4.0, abs=0.05)
    assert len(store.writes) == 1
    k = feed(book, k, 10.0, 3.0, rng)          # a lower quiet level, 10 s later: not searched yet
    search()
    assert book.baselines["DDR_AB"].power_w > 3.5 and len(store.writes) == 1
    k = feed(book, k, 20.0, 5.0, rng)          # 30 s of new samples since the first search
    search()                                    # the 3 W stretch is still in the 60 s history: found
    assert book.baselines["DDR_AB"].power_w == pytest.approx(3.0, abs=0.05)
    assert len(store.writes) == 2
