"""The state database off the poll loop: every write and every large read on one store thread.

A full disk or a database another process holds locked must neither block the poll loop nor end
the daemon. :class:`StoreWorker` runs the store's calls on its own worker thread (in submission
order, so a run's records are written in the order they were made); a write that fails is kept and
retried before the next write and at every heartbeat, and the daemon reports itself degraded
(:meth:`StoreWorker.health`) until the backlog is written.

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

import collections
import logging
import time
from collections.abc import Callable
from typing import Any, TypeVar

from hdeem_watch.daemon.jobs import Worker
from hdeem_watch.daemon.ports import StorePort

log = logging.getLogger("hdeem_watch.daemon")

T = TypeVar("T")
Action = Callable[[StorePort], Any]

#: Pause of the store worker after each read: a crowd of ``runs.list`` callers must not keep the
#: poll loop waiting for the interpreter lock.
READ_PAUSE_S = 0.002
#: Failed writes kept for a retry (beyond it the oldest are dropped, with an error in the log).
MAX_BACKLOG = 10_000


class StoreWorker:
    """Store calls on a worker thread, failed writes retried.

    Args:
        store: the state database (used only from the worker thread once the loop runs).
        wake: called from the worker thread when a call finishes (wakes the poll loop).
    """

    def __init__(self, store: StorePort, wake: Callable[[], None] | None = None) -> None:
        self.store = store
        self.jobs = Worker("store", wake)
        self._backlog: collections.deque[tuple[str, Action]] = collections.deque()
        self._error: str | None = None  # written on the worker, read in the loop (one str: atomic)

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
        """``"ok"``, or ``"degraded: <why>"`` while writes wait for the disk (here, or in the
        store's own writer, which keeps failed writes in memory and retries them)."""
        if self._error is not None:
            return f"degraded: {self._error}"
        try:
            return str(self.store.health())
        except Exception as error:  # a store without a health report is not a reason to fail
            return f"degraded: store health unknown: {type(error).__name__}"

    def write(self, what: str, action: Action, done: Callable[[bool], None] | None = None) -> None:
        """Run ``action(store)`` on the worker; ``done(written)`` in the loop: False when the write
        is kept for a retry here, or when ``action`` returned False (the store keeps it in memory
        and retries it: not on disk yet)."""

        def job() -> bool:
            self._drain()
            if self._backlog:
                self._keep(what, action)
                return False
            return self._attempt(what, action)

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

    def retry(self) -> None:
        """Try the failed writes again (at every heartbeat)."""
        if self._backlog:
            self.jobs.submit(self._drain, _ignore, None)

    def shutdown(self) -> None:
        """Finish every queued call (one last retry of the backlog) and run their callbacks."""
        self.retry()
        self.jobs.shutdown()
        if self._backlog:
            log.error("%d store writes could not be made before exit: %s", len(self._backlog), self._error)

    # -- on the worker ------------------------------------------------------------------------

    def _attempt(self, what: str, action: Action) -> bool:
        try:
            written = action(self.store)
        except Exception as error:
            self._keep(what, action)
            reason = f"{what}: {type(error).__name__}: {error}"
            if self._error is None:
                log.error("state database write failed (kept for a retry): %s", reason)
            self._error = reason
            return False
        return written is not False

    def _keep(self, what: str, action: Action) -> None:
        self._backlog.append((what, action))
        if len(self._backlog) > MAX_BACKLOG:
            lost, _ = self._backlog.popleft()
            log.error("state database backlog full: dropped %s", lost)

    def _drain(self) -> None:
        while self._backlog:
            what, action = self._backlog[0]
            try:
                action(self.store)
            except Exception as error:
                self._error = f"{what}: {type(error).__name__}: {error}"
                return
            self._backlog.popleft()
        if self._error is not None:
            log.warning("state database writable again; backlog written")
        self._error = None


def _ignore(_result: Any) -> None:
    return None
