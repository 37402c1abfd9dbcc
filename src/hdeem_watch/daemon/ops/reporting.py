"""What the daemon tells the world: heartbeat, calibration and baselines.

The :class:`Reporter` reads the run book (:class:`~hdeem_watch.daemon.book.state.NodeState`), the
calibration and the source's health through narrow ports, and publishes the ``status``, ``calib``
and ``baseline`` topics; new baselines are stored through the store worker (never on the loop).
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import psutil

from hdeem_watch.daemon.book import baselines as bl
from hdeem_watch.daemon.book.state import NodeState
from hdeem_watch.daemon.ops.ports import PublisherPort
from hdeem_watch.daemon.shell.workers import Calibration
from hdeem_watch.daemon.store.port import StorePort
from hdeem_watch.daemon.store.worker import StoreWorker
from hdeem_watch.sources.base import HasTruth, Source
from hdeem_watch.wire.protocol import EncodedResult

Clock = Callable[[], int]

#: The sim's hidden truth is computed again after this much source time: its currents drift over
#: hours, and each computation costs about a millisecond of the loop (``calib.get``, ``calib``).
TRUTH_MAX_AGE_S = 1.0


@dataclass(frozen=True)
class Identity:
    """What does not change while the daemon runs (in every status body)."""

    kind: str
    endpoints: Mapping[str, Any]
    curve_public_key: str | None = None
    prometheus_port: int | None = None


class Reporter:
    """Heartbeat, calibration and baseline publishing of one node.

    Args:
        book: the node's run book.
        calibration: the calibration (its ``calib`` body).
        source: the source (health; truth when it :class:`~hdeem_watch.sources.base.HasTruth`).
        publisher: where the topics go.
        store: the store worker (baselines written there; its health in the status).
        identity: the static part of the status.
        poll_interval_ns: the current poll period.
        clock: the monotonic clock (uptime).
    """

    def __init__(self, book: NodeState, calibration: Calibration, source: Source, publisher: PublisherPort,
                 store: StoreWorker, identity: Identity, *, poll_interval_ns: Callable[[], int],
                 clock: Clock) -> None:
        self.book = book
        self.calibration = calibration
        self.source = source
        self.publisher = publisher
        self.store = store
        self.identity = identity
        self._poll_interval_ns = poll_interval_ns
        self._clock = clock
        self._t_open_ns = clock()
        self._process = psutil.Process()
        self._cpu_mark = (time.process_time_ns(), time.monotonic_ns())
        self._cpu_percent = math.nan
        self._searched_t_ns: int | None = None
        self._truth: dict[str, Any] | None = None
        self._truth_at_ns: int | None = None
        self._truth_max_age_ns = round(TRUTH_MAX_AGE_S * 1e9 / book.speed)
        self._calib_reply: tuple[dict[str, Any], dict[str, Any] | None, EncodedResult] | None = None

    def source_health(self) -> str:
        """The source's own health, or the last poll failure while polls fail."""
        try:
            health = str(self.source.health())
        except Exception as error:
            health = f"error: {error}"
        failure = self.book.poll_error
        return failure if failure is not None and health == "ok" else health

    def status_body(self) -> dict[str, Any]:
        """The heartbeat body (also the base of the ``status`` op)."""
        run = self.book.running()
        return {
            "source": {"kind": self.identity.kind, "health": self.source_health()},
            "store": {"health": self.store.health()},
            "channels": {name: a.status_entry() for name, a in self.book.accounts.items()},
            "process": {"cpu_percent": self._cpu_percent, "rss_bytes": int(self._process.memory_info().rss),
                        "pid": os.getpid()},
            "run": None if run is None else run.to_dict(),
            "uptime_s": (self._clock() - self._t_open_ns) / 1e9,
            "endpoints": dict(self.identity.endpoints),
            "curve_public_key": self.identity.curve_public_key,
            "speed": self.book.speed,
            "poll_interval_s": self._poll_interval_ns() / 1e9,
            "prometheus_port": self.identity.prometheus_port,
        }

    def publish_status(self) -> None:
        """Publish the heartbeat (rates over the last heartbeat period, CPU share since the last)."""
        self._cpu_percent = self._cpu_share()
        self.book.heartbeat()
        self.publisher.publish("status", self.status_body())

    def _cpu_share(self) -> float:
        """Percent of one core the daemon's threads used since the previous call (the process CPU
        clock over real time; psutil's ``cpu_percent`` parsed ``/proc`` for the same figure)."""
        cpu, wall = time.process_time_ns(), time.monotonic_ns()
        (cpu_before, wall_before), self._cpu_mark = self._cpu_mark, (cpu, wall)
        return 100.0 * (cpu - cpu_before) / (wall - wall_before) if wall > wall_before else math.nan

    def truth(self) -> dict[str, Any] | None:
        """The simulated source's hidden truth (computed again after :data:`TRUTH_MAX_AGE_S` of source
        time), or None for real sensors."""
        if not isinstance(self.source, HasTruth):
            return None
        now = self._clock()
        if self._truth_at_ns is not None and now - self._truth_at_ns < self._truth_max_age_ns:
            return self._truth
        try:
            truth: dict[str, Any] | None = dict(self.source.truth())
        except Exception:
            truth = None
        self._truth, self._truth_at_ns = truth, now
        return truth

    def calib_with_truth(self) -> dict[str, Any]:
        """The latest ``calib`` body with the sim's truth now."""
        return {**self.calibration.body, "truth": self.truth()}

    def calib_reply(self) -> EncodedResult:
        """``calib.get``'s result, encoded once per calibration body and truth (a crowd of clients
        asking for it costs one encoding, not one each)."""
        body, truth = self.calibration.body, self.truth()
        cached = self._calib_reply
        if cached is None or cached[0] is not body or cached[1] is not truth:
            cached = self._calib_reply = (body, truth, EncodedResult.of({**body, "truth": truth}))
        return cached[2]

    def publish_calib(self) -> None:
        """Publish the ``calib`` body (cached by the publisher for late joiners)."""
        self.publisher.publish("calib", self.calib_with_truth())

    def publish_baselines(self) -> None:
        """Publish the ``baseline`` body (cached for late joiners)."""
        self.publisher.publish("baseline", bl.baselines_body(self.book.baselines))

    def baselines_kept(self, kept: Mapping[str, bl.Baseline]) -> None:
        """Store and publish baselines that replaced the kept ones (nothing when empty)."""
        if not kept:
            return
        # One store call for all of them: one wake-up of the store threads, not one per channel.
        records = {channel: baseline.to_dict() for channel, baseline in kept.items()}
        self.store.write(f"baselines {', '.join(records)}", _save_baselines(records))
        self.publish_baselines()

    def look_for_quiet_periods(self, *, window_s: float, max_spread_w: float, history_s: float) -> None:
        """Baselines from quiet periods of the recent samples (only while no window is open).

        A window stays in the ``history_s`` of kept samples for ``history_s - window_s`` of sample
        time, so a search every half history (of sample time) sees every window at least once; the
        searches between would only find the same windows again (a search reads every kept sample).
        """
        newest = self.book.newest_dram_sample_ns()
        if newest is None:
            return
        if self._searched_t_ns is not None and newest - self._searched_t_ns < history_s * 0.5e9:
            return
        self._searched_t_ns = newest
        self.baselines_kept(self.book.quiet_baselines(window_s=window_s, max_spread_w=max_spread_w))


def _save_baselines(records: Mapping[str, dict[str, Any]]) -> Callable[[StorePort], None]:
    def save(store: StorePort) -> None:
        for channel, record in records.items():
            store.save_baseline(channel, record)

    return save
