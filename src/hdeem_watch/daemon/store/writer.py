"""The state database's writer: one thread that applies writes in order and retries what fails.

The daemon's loop must never wait for the disk nor die of it. A write is handed to
:class:`BackgroundWriter` as an opaque operation; the writer applies it on its own SQLite
connection and, when that fails (disk full, read-only file system, another process holding the
write lock, an I/O error), keeps it at the head of the queue and tries again with a growing pause
(0.2 s … 5 s), reporting ``degraded: <reason>`` meanwhile. Operations are never reordered and never
dropped for an I/O error; one that fails for any other reason (a bug) is logged and skipped so it
cannot wedge the queue.

Example:
    >>> import sqlite3
    >>> done = []
    >>> writer = BackgroundWriter(lambda: sqlite3.connect(":memory:"), lambda db, op: done.append(op))
    >>> writer.submit("a"), writer.submit("b")
    (1, 2)
    >>> writer.flush(5.0), done, writer.health
    (True, ['a', 'b'], 'ok')
    >>> writer.close(1.0)
    []
"""

from __future__ import annotations

import collections
import logging
import sqlite3
import threading
import time
from collections.abc import Callable, Hashable

log = logging.getLogger("hdeem_watch.daemon.store.database")

Connect = Callable[[], sqlite3.Connection]
Apply = Callable[[sqlite3.Connection, Hashable], None]


class BackgroundWriter:
    """Applies operations in submission order on a thread of its own, retrying I/O failures.

    Args:
        connect: opens the writer's connection (called on the writer thread; retried on failure).
        apply: writes one operation in one transaction, raising ``sqlite3.Error``/``OSError`` on
            failure (and leaving nothing half-written).
        retry_min_s: first pause after a failure; doubled each time up to ``retry_max_s``.
        retry_max_s: longest pause between two tries.
        clock: monotonic seconds (injected for tests).
    """

    def __init__(self, connect: Connect, apply: Apply, *, retry_min_s: float = 0.2, retry_max_s: float = 5.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._connect = connect
        self._apply = apply
        self._retry = (retry_min_s, retry_max_s)
        self._clock = clock
        self._queue: collections.deque[Hashable] = collections.deque()
        self._cond = threading.Condition()
        self._closing = False
        self._busy = False
        self._submitted = self._completed = 0
        self._health = "ok"
        self.failures = 0
        self.written = 0
        self._thread = threading.Thread(target=self._run, name="hdeem-watch-state-writer", daemon=True)
        self._thread.start()

    @property
    def health(self) -> str:
        """``"ok"``, or ``"degraded: <reason>"`` while writes are failing."""
        return self._health

    @property
    def completed(self) -> int:
        """Tickets written so far (every ticket up to this one is written)."""
        return self._completed

    @property
    def pending(self) -> int:
        """Operations submitted and not yet written."""
        with self._cond:
            return len(self._queue)

    def submit(self, op: Hashable) -> int:
        """Queue ``op`` (returns at once); its ticket for :meth:`wait_for`."""
        with self._cond:
            self._queue.append(op)
            self._submitted += 1
            self._cond.notify_all()
            return self._submitted

    def wait_for(self, ticket: int, timeout_s: float) -> bool:
        """Wait until the operation of ``ticket`` (and every earlier one) is written; False on timeout."""
        deadline = self._clock() + timeout_s
        with self._cond:
            while self._completed < ticket:
                left = deadline - self._clock()
                if left <= 0:
                    return False
                self._cond.wait(left)
        return True

    def flush(self, timeout_s: float) -> bool:
        """Wait until everything submitted is written; False when ``timeout_s`` passed first."""
        deadline = self._clock() + timeout_s
        with self._cond:
            while self._queue or self._busy:
                left = deadline - self._clock()
                if left <= 0:
                    return False
                self._cond.wait(min(left, 0.05))
        return True

    def close(self, timeout_s: float) -> list[Hashable]:
        """Write what is pending for up to ``timeout_s``, stop the thread; return what is left unwritten."""
        self.flush(timeout_s)
        with self._cond:
            self._closing = True
            self._cond.notify_all()
        self._thread.join(timeout=max(1.0, timeout_s))
        with self._cond:
            return list(self._queue)

    # -- the thread ------------------------------------------------------------------------------------

    def _run(self) -> None:
        db: sqlite3.Connection | None = None
        pause = self._retry[0]
        while True:
            with self._cond:
                while not self._queue and not self._closing:
                    self._cond.wait()
                if self._closing:
                    break
                op = self._queue[0]
                self._busy = True
            try:
                if db is None:
                    db = self._connect()
                self._apply(db, op)
            except (sqlite3.Error, OSError) as error:
                self.failures += 1
                reason = f"degraded: state database not writable ({error})"
                if reason != self._health:
                    log.warning("%s; writes are kept in memory and retried", reason[len("degraded: "):])
                self._health = reason
                if db is not None and not _usable(db, error):
                    db.close()
                    db = None
                with self._cond:
                    self._busy = False
                    self._cond.notify_all()
                    if not self._closing:
                        self._cond.wait(pause)
                pause = min(pause * 2, self._retry[1])
                continue
            except Exception:
                log.exception("state write %r failed; skipped", op)
            if self._health != "ok":
                log.warning("state database writable again")
            self._health, pause = "ok", self._retry[0]
            self.written += 1
            with self._cond:
                if self._queue and self._queue[0] is op:
                    self._queue.popleft()
                    self._completed += 1
                self._busy = False
                self._cond.notify_all()
        if db is not None:
            db.close()


def _usable(db: sqlite3.Connection, error: BaseException) -> bool:
    """Whether ``db`` may be used again after ``error`` (rolled back); False: reopen it."""
    try:
        if db.in_transaction:
            db.execute("ROLLBACK")
    except sqlite3.Error:
        return False
    return "malformed" not in str(error) and "not a database" not in str(error)
