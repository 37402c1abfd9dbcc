"""The daemon's memory-controller counters in the poll loop: a counter source, its windows and recorder.

:class:`CounterFeed` is what the service holds when the ``counters`` setting is not ``none``: it
reads the counter source when due (each heartbeat, at window edges, while a new window has no
start), gives the run book's windows their starts, attaches a closed run window's counts to its
record, publishes the ``counters`` topic and records snapshots beside ``--record``. A read that
fails is logged once and shown in the topic's ``status``; the daemon goes on (docs/counters.md).
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from hdeem_watch.daemon.counters.windows import CounterWindows, ExactCounters
from hdeem_watch.errors import InputError

if TYPE_CHECKING:
    from hdeem_watch.daemon.book.state import NodeState

__all__ = ["CounterFeed"]

log = logging.getLogger("hdeem_watch.daemon")


class CounterFeed:
    """A counter source read into :class:`CounterWindows` (and a recorder), for one run book.

    Args:
        counters: the counter source (:mod:`hdeem_watch.counters.setting`).
        book: the run book whose windows get counter starts.
        clock: monotonic ns.
        heartbeat_s: read at least this often.
        recorder: writes every snapshot (``--record``), or None.
    """

    def __init__(self, counters: Any, book: NodeState, *, clock: Callable[[], int], heartbeat_s: float,
                 recorder: Any = None) -> None:
        self.source = counters
        self.book = book
        self.clock = clock
        self.recorder = recorder
        #: counts at an exact time, where the source can (:class:`ExactCounters`: the sim's); None: interpolated
        self.exact = counters.read_at if isinstance(counters, ExactCounters) else None
        self.windows = CounterWindows(
            counters.kind, table_key=counters.table.generation, ranks=counters.ranks,
            refresh_complete=counters.table.refresh_complete,
            sensors={c.name: c.sensor for c in counters.channels()},
            heartbeat_ns=round(heartbeat_s * 1e9))

    @classmethod
    def open(cls, kind: str, source: object, book: NodeState, *, memspec: str, clock: Callable[[], int],
             heartbeat_s: float, record_file: str | None, replay_file: str | None,
             source_kind: str = "", notes: list[str] | None = None) -> CounterFeed | None:
        """The feed of the ``counters`` setting ``kind``, read once; None for ``none`` (or no source).

        ``auto`` tries the counters of the power source ``source_kind``
        (:func:`~hdeem_watch.counters.source.auto_counter_kind`) and falls back to none when they
        cannot be opened; either way it says, once, which commands the fits will use: a line
        appended to ``notes`` for the caller to log once the daemon has started (logged here if None).

        Raises:
            InputError: the memspec is unknown, the counters of an explicit kind cannot be opened
                (the source's reason), or the record file cannot be written.
        """
        if kind == "none":
            return None
        from hdeem_watch.calibrate.run_model import load_spec

        ranks = int(load_spec(memspec).nbr_of_ranks)  # per channel: one DIMM of the node's memspec
        if kind == "auto":
            counters, note = _auto_counter_source(source, book, clock=clock, ranks=ranks,
                                                  replay_file=replay_file, source_kind=source_kind)
            if notes is None:
                log.info("%s", note)
            else:
                notes.append(note)
        else:
            counters = _counter_source(kind, source, book, clock=clock, ranks=ranks, replay_file=replay_file)
        if counters is None:
            return None
        recorder = None
        if record_file:
            from hdeem_watch.daemon.counters.record import CounterRecorder, counters_path

            path = counters_path(record_file)
            try:
                recorder = CounterRecorder(path, kind=counters.kind, table=counters.table, ranks=counters.ranks,
                                           channels=counters.channels())
            except OSError as error:
                with contextlib.suppress(Exception):
                    counters.close()
                raise InputError(f"record file {path}: {error.strerror}") from None
        feed = cls(counters, book, clock=clock, heartbeat_s=heartbeat_s, recorder=recorder)
        feed.read(force=True)
        return feed

    def read(self, *, force: bool = False) -> None:
        """Read the counters when due (heartbeat, window edges) or ``force``d; give new windows their start."""
        windows, book, now = self.windows, self.book, self.clock()
        if force or windows.due(now, book.windows):
            try:
                snapshot = self.source.read()
                windows.observe(snapshot, now_mono_ns=now)
                if self.recorder is not None:
                    self.recorder.write(snapshot)
            except Exception as error:  # a counter failure must not end the daemon
                if windows.error is None:
                    log.warning("counter read failed: %s", error)
                windows.failed(error, now_mono_ns=now)
        if book.windows:
            windows.track(book.windows, book.sample_time_of, self.exact)

    def window_closed(self, closed: Any) -> None:
        """Attach the counters of a closed run window to its record (before it is stored and modelled)."""
        run = closed.run
        if run is None:
            return
        if run.state == "aborted":
            self.windows.forget(run.run_id)
            return
        run.counters = self.windows.finish(run, self.book.dram_channels, self.exact)

    def rates_body(self) -> dict[str, Any]:
        """The ``counters`` topic's body: per channel ACT/s, RD/s, WR/s and power-down share."""
        windows = self.windows
        return {"source": windows.kind, "generation": windows.table_key, "status": windows.error or "ok",
                "channels": {name: {**values, "sensor": windows.sensors.get(name)}
                             for name, values in windows.rates().items()}}

    def flush(self) -> None:
        """Flush the recorder (each heartbeat)."""
        if self.recorder is not None:
            self.recorder.flush()

    def close(self) -> None:
        """Close the counter source and the recorder."""
        with contextlib.suppress(Exception):
            self.source.close()
        if self.recorder is not None:
            self.recorder.close()
            self.recorder = None


def _counter_source(kind: str, source: object, book: NodeState, *, clock: Callable[[], int], ranks: int,
                    replay_file: str | None) -> Any:
    """The counter source of an explicit ``counters`` kind (None for ``none``); InputError if it cannot open."""
    from hdeem_watch.counters.setting import make_counter_source
    from hdeem_watch.daemon.counters.record import CounterReplay

    replay = (lambda: CounterReplay(replay_file, source)) if replay_file else None
    return make_counter_source(kind, source, sample_time=book.sample_time_of,
                               clock=clock, ranks=ranks if kind == "perf" else 2, replay=replay)


def _auto_counter_source(source: object, book: NodeState, *, clock: Callable[[], int], ranks: int,
                         replay_file: str | None, source_kind: str) -> tuple[Any, str]:
    """``counters = "auto"``: the power source's own counters if they open, else None; and the line
    that says which commands the fits use."""
    from hdeem_watch.counters.source import auto_counter_kind
    from hdeem_watch.daemon.counters.record import counters_path

    has_recorded = replay_file is not None and counters_path(replay_file).is_file()
    kind = auto_counter_kind(source_kind, replay_has_counters=has_recorded)
    fallback = "fits use the kernel model's commands (calib show: 'modelled')"
    if kind == "none":
        return None, f"counters: none (auto: the {source_kind or 'power'} source has no counters); {fallback}"
    try:
        counters = _counter_source(kind, source, book, clock=clock, ranks=ranks, replay_file=replay_file)
    except InputError as error:
        return None, f"counters: none (auto: {error}); {fallback}"
    return counters, (f"counters: {kind} (auto); fits use the commands counted in each window "
                      "(calib show: 'counted')")
