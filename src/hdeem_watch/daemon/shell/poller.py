"""Fixed-rate deadlines that skip missed ticks instead of bursting to catch up.

The daemon polls its source every ``interval`` on the monotonic clock. If it falls behind (a slow
sensor call, a stopped process, a loaded machine) the missed deadlines are skipped: the next tick is
the first deadline still in the future, so there is never a burst of back-to-back polls. No data is
lost by skipping: a source returns every sample due since the previous poll, and energies are
cumulative.

Example:
    >>> now = [0]
    >>> timer = IntervalTimer(100, clock=lambda: now[0])
    >>> timer.due(), timer.remaining_ns()
    (False, 100)
    >>> now[0] = 350                    # three deadlines passed (100, 200, 300)
    >>> timer.due(), timer.advance(), timer.next_ns
    (True, 2, 400)
"""

from __future__ import annotations

import time
from collections.abc import Callable

Clock = Callable[[], int]


def next_deadline(start_ns: int, interval_ns: int, now_ns: int) -> tuple[int, int]:
    """The first deadline ``start + k·interval`` strictly after ``now`` and how many were skipped.

    ``start_ns`` is the deadline that just fell due; ticks between it and ``now`` are skipped.

    >>> next_deadline(100, 100, 100)
    (200, 0)
    >>> next_deadline(100, 100, 350)
    (400, 2)
    """
    if interval_ns <= 0:
        raise ValueError(f"interval_ns = {interval_ns}: expected > 0")
    if now_ns < start_ns:
        return start_ns + interval_ns, 0
    k = (now_ns - start_ns) // interval_ns + 1
    return start_ns + k * interval_ns, int(k - 1)


class IntervalTimer:
    """A fixed-rate deadline on an injectable monotonic clock (integer ns).

    Args:
        interval_ns: the period.
        clock: monotonic clock in ns (default :func:`time.monotonic_ns`).
        start_ns: the first deadline (default: one interval from now).

    Attributes:
        next_ns: the next deadline.
        skipped: deadlines skipped so far.
        ticks: deadlines served so far.
    """

    def __init__(self, interval_ns: int, *, clock: Clock = time.monotonic_ns, start_ns: int | None = None) -> None:
        if interval_ns <= 0:
            raise ValueError(f"interval_ns = {interval_ns}: expected > 0")
        self.interval_ns = int(interval_ns)
        self._clock = clock
        self.next_ns = clock() + self.interval_ns if start_ns is None else int(start_ns)
        self.skipped = 0
        self.ticks = 0

    def set_interval(self, interval_ns: int) -> None:
        """Change the period; the next deadline moves to at most one new period from now."""
        if interval_ns <= 0:
            raise ValueError(f"interval_ns = {interval_ns}: expected > 0")
        self.interval_ns = int(interval_ns)
        self.next_ns = min(self.next_ns, self._clock() + self.interval_ns)

    def remaining_ns(self) -> int:
        """Nanoseconds until the next deadline (0 when due)."""
        return max(0, self.next_ns - self._clock())

    def due(self) -> bool:
        """Whether the next deadline has passed."""
        return self._clock() >= self.next_ns

    def advance(self, now_ns: int | None = None) -> int:
        """Serve the due deadline: move to the next future one; return how many were skipped.

        ``now_ns``: the clock's time if the caller has just read it (saves a read).
        """
        now = self._clock() if now_ns is None else now_ns
        if self.next_ns <= now < self.next_ns + self.interval_ns:  # on time: the next tick
            self.next_ns += self.interval_ns
            self.ticks += 1
            return 0
        self.next_ns, skipped = next_deadline(self.next_ns, self.interval_ns, now)
        self.skipped += skipped
        self.ticks += 1
        return skipped


def wait_ms(timers: list[IntervalTimer], cap_ms: int = 1000) -> int:
    """Milliseconds to wait until the earliest of ``timers`` is due (rounded up, ≤ ``cap_ms``)."""
    if not timers:
        return cap_ms
    remaining = min(t.remaining_ns() for t in timers)
    return min(cap_ms, -(-remaining // 1_000_000))
