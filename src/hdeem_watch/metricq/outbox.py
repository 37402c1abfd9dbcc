"""The bounded buffer between the daemon's stream and MetricQ.

The stream is read without pause; what MetricQ has not yet taken waits here. While the broker is
unreachable the buffer fills up to ``capacity`` data points, then the oldest points go first and
are counted in :attr:`Outbox.dropped` (the stream reader never waits for the broker). Points that
failed to publish are put back in front (:meth:`Outbox.requeue`), so a broker restart loses
nothing that fits in the buffer.

Example:
    >>> import numpy as np
    >>> box = Outbox(capacity=3)
    >>> box.push([Points("m", np.array([1, 2]), np.array([1.0, 2.0]))])
    >>> box.push([Points("m", np.array([3, 4]), np.array([3.0, 4.0]))])
    >>> len(box), box.dropped
    (3, 1)
    >>> [p.t_ns.tolist() for p in box.take()]
    [[2], [3, 4]]
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable

from hdeem_watch.metricq.translate import Points


class Outbox:
    """FIFO of :class:`~hdeem_watch.metricq.translate.Points` holding at most ``capacity`` values."""

    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            raise ValueError(f"capacity {capacity}: expected >= 1")
        self.capacity = capacity
        self.dropped = 0
        self._queue: deque[Points] = deque()
        self._size = 0

    def __len__(self) -> int:
        return self._size

    def push(self, points: Iterable[Points]) -> None:
        """Append ``points`` at the end, dropping the oldest values beyond the capacity."""
        for p in points:
            if len(p):
                self._queue.append(p)
                self._size += len(p)
        self._trim()

    def requeue(self, points: list[Points]) -> None:
        """Put ``points`` (taken earlier, not published) back in front, in their order."""
        for p in reversed(points):
            self._queue.appendleft(p)
            self._size += len(p)
        self._trim()

    def take(self) -> list[Points]:
        """Everything waiting, oldest first; the outbox is empty afterwards."""
        out = list(self._queue)
        self._queue.clear()
        self._size = 0
        return out

    def _trim(self) -> None:
        while self._size > self.capacity:
            head = self._queue[0]
            excess = self._size - self.capacity
            if excess >= len(head):
                self._queue.popleft()
                self._size -= len(head)
                self.dropped += len(head)
            else:
                self._queue[0] = Points(head.metric, head.t_ns[excess:], head.values[excess:])
                self._size -= excess
                self.dropped += excess
