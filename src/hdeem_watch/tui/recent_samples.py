"""The recent samples of one channel that the UI plots: a fixed-capacity ring of timed samples
(int64 ns, float64 W), read back by time window.

(Not the daemon's per-channel history: this one belongs to the UI's node model and holds the
longest plot window at the channel's rate.)

Appending is O(batch) with numpy slices; reading a time window returns its samples in time order.
The buffer forgets the oldest samples when full, so memory stays bounded however long the UI runs.

Example:
    >>> import numpy as np
    >>> ring = RecentSamples(capacity=4)
    >>> ring.extend(np.array([1, 2, 3]), np.array([1.0, 2.0, 3.0]))
    >>> ring.extend(np.array([4, 5]), np.array([4.0, 5.0]))
    >>> ring.window(0, 10)[0].tolist()
    [2, 3, 4, 5]
"""

from __future__ import annotations

import numpy as np


class RecentSamples:
    """The last ``capacity`` samples of one channel, for the plots.

    Args:
        capacity: how many samples to keep (at least 1).
    """

    def __init__(self, capacity: int) -> None:
        self.capacity = max(1, int(capacity))
        self._t_ns = np.zeros(self.capacity, dtype=np.int64)
        self._power_w = np.full(self.capacity, np.nan, dtype=np.float64)
        self._start = 0  # index of the oldest sample
        self._size = 0

    def __len__(self) -> int:
        return self._size

    def clear(self) -> None:
        """Forget every sample."""
        self._start = 0
        self._size = 0

    def extend(self, t_ns: np.ndarray, power_w: np.ndarray) -> None:
        """Append samples (assumed in time order; older-than-newest samples are still kept)."""
        n = len(t_ns)
        if n == 0:
            return
        if n >= self.capacity:
            self._t_ns[:] = t_ns[-self.capacity :]
            self._power_w[:] = power_w[-self.capacity :]
            self._start = 0
            self._size = self.capacity
            return
        end = (self._start + self._size) % self.capacity
        first = min(n, self.capacity - end)
        self._t_ns[end : end + first] = t_ns[:first]
        self._power_w[end : end + first] = power_w[:first]
        if first < n:
            self._t_ns[: n - first] = t_ns[first:]
            self._power_w[: n - first] = power_w[first:]
        overflow = self._size + n - self.capacity
        if overflow > 0:
            self._start = (self._start + overflow) % self.capacity
            self._size = self.capacity
        else:
            self._size += n

    def _segments(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """The stored samples as one or two time-ordered views (no copy)."""
        end = self._start + self._size
        if end <= self.capacity:
            return [(self._t_ns[self._start : end], self._power_w[self._start : end])]
        wrap = end - self.capacity
        return [
            (self._t_ns[self._start :], self._power_w[self._start :]),
            (self._t_ns[:wrap], self._power_w[:wrap]),
        ]

    def window(self, t_from_ns: int, t_to_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """Samples with ``t_from_ns <= t < t_to_ns`` in time order.

        The result may be a view into the ring: read it before the next :meth:`extend`.
        """
        parts_t = []
        parts_p = []
        for t, p in self._segments():
            lo = int(np.searchsorted(t, t_from_ns, side="left"))
            hi = int(np.searchsorted(t, t_to_ns, side="left"))
            if hi > lo:
                parts_t.append(t[lo:hi])
                parts_p.append(p[lo:hi])
        if not parts_t:
            return np.empty(0, dtype=np.int64), np.empty(0, dtype=np.float64)
        if len(parts_t) == 1:
            return parts_t[0], parts_p[0]
        return np.concatenate(parts_t), np.concatenate(parts_p)

    def last(self) -> tuple[int, float] | None:
        """The newest sample ``(t_ns, power_w)``, None when empty."""
        if self._size == 0:
            return None
        i = (self._start + self._size - 1) % self.capacity
        return int(self._t_ns[i]), float(self._power_w[i])

    def newest_t_ns(self) -> int | None:
        """Time of the newest sample, None when empty."""
        last = self.last()
        return None if last is None else last[0]
