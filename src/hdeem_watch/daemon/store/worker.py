"""The state database off the poll loop: every store call on one thread, every write on the store's writer.

A full disk or a database another process holds locked must neither block the poll loop nor end
the daemon. :class:`StoreWorker` runs the store's calls on a thread of its own (in submission
order, so a run's records are handed to the store in the order they were made): the large reads,
and the serialising of each write. It keeps no writes and retries nothing: the store's single
writer thread (:class:`~hdeem_watch.daemon.store.writer.BackgroundWriter`) owns the write queue,
its one retry policy (0.2 s … 5 s, never dropping a write for an I/O error) and the one health
(:meth:`StoreWorker.health` is :meth:`Store.health <hdeem_watch.daemon.store.database.Store.health>`).

Example:
    >>> class Memory:
    ...     def __init__(self): self.runs = {}
    ...     def save_run(self, record): self.runs[record["run_id"]] = record
    ...     def health(self): return "ok"
    >>> store = Memory()
    >>> writer = StoreWorker(store)                   # type: ignore[arg-type]
    >>> writer.write("run r1", lambda s: s.save_run({"run_id": "r1"}))
    >>> writer.shutdown(); sorted(store.runs), writer.health()
    (['r1'], 'ok')
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any, TypeVar

from hdeem_watch.daemon.ops.ports import StorePort
from hdeem_watch.daemon.shell.workers import Worker

log = logging.getLogger("hdeem_watch.daemon")

T = TypeVar("T")
Action = Callable[[StorePort], Any]

#: Pause of the store worker after each read: a crowd of ``runs.list`` callers must not keep the
#: poll loop waiting for the interpreter lock.
READ_PAUSE_S = 0.002


class StoreWorker:
    """Store calls on a thread of their own; the store's writer writes and retries.

    Args:
        store: the state database (used only from the worker thread once the loop runs).
        wake: called from the worker thread when a call finishes (wakes the poll loop).
    """

    def __init__(self, store: StorePort, wake: Callable[[], None] | None = None) -> None:
        self.store = store
        self.jobs = Worker("store", wake)

    @property
    def pending(self) -> bool:
        """Whether callbacks are waiting for :meth:`collect`."""
        return bool(self.jobs.pending)

    @property
    def ready(self) -> bool:
        """Whether a finished call's callback waits for :meth:`collect`."""
        return self.jobs.ready

    def collect(self, limit: int | None = None) -> None:
        """Run the callbacks of finished calls (in the loop), at most ``limit``."""
        self.jobs.collect(limit)

    def health(self) -> str:
        """The store's health: ``"ok"``, or ``"degraded: <why>"`` while its writer's writes wait
        for the disk (kept in memory and retried) or its file system refuses writes."""
        try:
            return str(self.store.health())
        except Exception as error:  # a store without a health report is not a reason to fail
            return f"degraded: store health unknown: {type(error).__name__}"

    def write(self, what: str, action: Action, done: Callable[[bool], None] | None = None) -> None:
        """Run ``action(store)`` on the worker; ``done(written)`` in the loop: False when ``action``
        returned False (the store's writer keeps the write in memory and retries it: not on disk
        yet) or raised (a record that cannot be serialised: a bug, logged, nothing to retry)."""

        def job() -> bool:
            try:
                return action(self.store) is not False
            except Exception:
                log.exception("state database write %s could not be made; skipped", what)
                return False

        self.jobs.submit(job, done or _ignore, None)

    def read(self, action: Callable[[StorePort], T], done: Callable[[T], None],
             failed: Callable[[BaseException], None]) -> None:
        """Run ``action(store)`` on the worker; ``done(result)`` or ``failed(error)`` in the loop."""
        def job() -> T:
            try:
                return action(self.store)
            finally:
                time.sleep(READ_PAUSE_S)  # hand the interpreter to the poll loop between large reads

        self.jobs.submit(job, done, failed)

    def shutdown(self) -> None:
        """Finish every queued call and run their callbacks (the store's close writes what waits)."""
        self.jobs.shutdown()


def _ignore(_result: Any) -> None:
    return None
