"""Per-channel bookkeeping of the daemon: latest value, cumulative energy, sample rate, gaps.

Gaps are found from the sample timestamps themselves (a step larger than 1.5 nominal periods means
``round(step / period) - 1`` samples are missing) plus whatever the source reports as missing. The
measured rate is counted in the source's own time (sample timestamps), so a sped-up simulation
reports its native rate, not its rate per wall-clock second.

Example:
    >>> import numpy as np
    >>> count_missing(np.array([0, 10, 40, 50]), rate_hz=1e8, prev_t_ns=None)
    2
    >>> acc = ChannelAccount("DDR_AB", 100.0, "dram")
    >>> acc.update(np.array([10_000_000, 20_000_000]), np.array([4.0, 5.0]), energy_j=0.09, status="ok")
    (2, 0, 0.09)
    >>> acc.power_w, acc.samples
    (5.0, 2)
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def count_missing(t_ns: np.ndarray, *, rate_hz: float, prev_t_ns: int | None) -> int:
    """Samples missing from a channel's regular grid in ``t_ns`` (and since ``prev_t_ns``)."""
    n = t_ns.size
    if rate_hz <= 0 or n == 0:
        return 0
    period = 1e9 / rate_hz
    if prev_t_ns is not None and int(t_ns[-1]) - prev_t_ns < (n + 0.5) * period and int(t_ns[0]) > prev_t_ns:
        return 0  # fast path: the batch spans no more than its samples (a regular, gap-free grid)
    times = t_ns.astype(np.int64, copy=False)
    if prev_t_ns is not None:
        steps = np.diff(times, prepend=np.int64(prev_t_ns))
    else:
        steps = np.diff(times)
    large = steps[steps > 1.5 * period]
    if large.size == 0:
        return 0
    return int(np.sum(np.rint(large / period) - 1))


class RecentPower:
    """A channel's recent power samples (the last ``capacity``, oldest first on read), where the
    daemon looks for quiet periods (idle baselines).

    Appending is cheap (the daemon appends every poll): batches are queued and folded into the ring
    when it is read or when ``fold_every`` batches are waiting.
    """

    def __init__(self, capacity: int, *, fold_every: int = 64) -> None:
        self.capacity = max(1, int(capacity))
        self._data = np.full(self.capacity, np.nan)
        self._pos = 0
        self._count = 0
        self._queued: list[np.ndarray] = []
        self._fold_every = max(1, int(fold_every))

    def extend(self, values: np.ndarray) -> None:
        """Append values (only the last ``capacity`` are kept)."""
        self._queued.append(values)
        if len(self._queued) >= self._fold_every:
            self._fold()

    def _fold(self) -> None:
        queued, self._queued = self._queued, []
        if not queued:
            return
        values = np.asarray(queued[0] if len(queued) == 1 else np.concatenate(queued), dtype=float)
        values = values[-self.capacity :]
        n = values.size
        end = self._pos + n
        if end <= self.capacity:
            self._data[self._pos : end] = values
        else:
            first = self.capacity - self._pos
            self._data[self._pos :] = values[:first]
            self._data[: n - first] = values[first:]
        self._pos = end % self.capacity
        self._count = min(self.capacity, self._count + n)

    def values(self) -> np.ndarray:
        """A copy of the stored samples, oldest first."""
        self._fold()
        if self._count < self.capacity:
            return self._data[: self._count].copy()
        return np.concatenate((self._data[self._pos :], self._data[: self._pos]))

    def clear(self) -> None:
        """Forget every sample."""
        self._queued = []
        self._pos = 0
        self._count = 0

    def __len__(self) -> int:
        self._fold()
        return self._count


class ChannelAccount:
    """State of one channel as the daemon sees it.

    Attributes:
        name, rate_hz, kind: from the source's :class:`ChannelInfo`.
        power_w: latest sample (NaN until the first, or when unknown).
        energy_j: the source's cumulative energy (NaN if unknown).
        status: the source's latest status.
        samples: samples received since start.
        gaps: samples missing since start.
        history: recent samples (DRAM channels), for quiet-period baselines.
        paced: each sample spans the time since the previous read (a ΔE/Δt source,
            :class:`~hdeem_watch.sources.base.QuietLimit`): a longer step is a slower read, not
            missing samples, so only the source's own report counts.
    """

    def __init__(self, name: str, rate_hz: float, kind: str, history_s: float = 60.0, *, paced: bool = False) -> None:
        self.name = name
        self.rate_hz = float(rate_hz)
        self.kind = kind
        self.power_w = math.nan
        self.energy_j = math.nan
        self.status = "ok"
        self.samples = 0
        self.gaps = 0
        self.last_t_ns: int | None = None
        self.history = RecentPower(round(history_s * rate_hz)) if kind == "dram" else None
        self._window_samples = 0
        self._window_start_t_ns: int | None = None
        self._period_ns = 1e9 / self.rate_hz if self.rate_hz > 0 else math.inf
        self.measured_rate_hz = math.nan
        self.paced = paced

    def update(
        self,
        t_ns: np.ndarray,
        power_w: np.ndarray,
        *,
        energy_j: float,
        status: str,
        reported_missing: int = 0,
        keep_history: bool = True,
    ) -> tuple[int, int, float]:
        """Take one batch; return ``(samples, missing, energy delta in J)`` (delta NaN if unknown).

        ``keep_history=False`` leaves the samples out of the quiet-period history (during runs).
        """
        before_energy, before_samples, before_gaps = self.energy_j, self.samples, self.gaps
        self.take(t_ns, power_w, energy_j, status, reported_missing, keep_history)
        delta = float(energy_j) - before_energy if math.isfinite(before_energy) else math.nan
        if before_samples == 0 and not math.isfinite(before_energy):
            delta = float(energy_j)
        return self.samples - before_samples, self.gaps - before_gaps, delta

    def take(self, t_ns: np.ndarray, power_w: np.ndarray, energy_j: float, status: str, reported_missing: int,
             keep_history: bool) -> bool:
        """:meth:`update` without its return value, on the daemon's hot path (25 times a second per
        channel); return whether the batch says anything new (samples, a new status or a new finite
        energy), i.e. whether to publish it."""
        energy_j = float(energy_j)
        news = status != self.status or (energy_j != self.energy_j and math.isfinite(energy_j))
        self.energy_j = energy_j
        self.status = status
        n = len(t_ns)
        if not n:
            if reported_missing > 0:
                self.gaps += int(reported_missing)
            return news
        last, previous = t_ns.item(-1), self.last_t_ns
        if self.paced or (previous is not None and last - previous < (n + 0.5) * self._period_ns
                          and t_ns.item(0) > previous):
            missing = 0  # paced, or the batch spans no more than its samples: a regular, gap-free grid
        else:
            missing = count_missing(t_ns, rate_hz=self.rate_hz, prev_t_ns=previous)
        if self._window_start_t_ns is None:
            self._window_start_t_ns = previous if previous is not None else t_ns.item(0)
            self._window_samples = 0 if previous is not None else -1
        if reported_missing > missing:
            missing = int(reported_missing)
        self.last_t_ns = last
        self.power_w = power_w.item(-1)
        self._window_samples += n
        if self.history is not None and keep_history:
            self.history.extend(power_w)
        self.samples += n
        self.gaps += missing
        return True

    def close_rate_window(self) -> float:
        """The rate measured since the previous call (samples per second of sample time)."""
        start, end = self._window_start_t_ns, self.last_t_ns
        if start is not None and end is not None and end > start and self._window_samples > 0:
            self.measured_rate_hz = self._window_samples * 1e9 / (end - start)
            self._window_start_t_ns = end
            self._window_samples = 0
        return self.measured_rate_hz

    def status_entry(self) -> dict[str, Any]:
        """This channel's entry in the status heartbeat."""
        return {
            "rate_hz": self.measured_rate_hz,
            "nominal_hz": self.rate_hz,
            "kind": self.kind,
            "gaps": self.gaps,
            "samples": self.samples,
            "status": self.status,
            "power_w": self.power_w,
            "energy_j": self.energy_j,
        }
