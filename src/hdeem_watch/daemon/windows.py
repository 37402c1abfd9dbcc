"""Measurement windows on the stream of polls: an open window, then a closing one, then closed.

A window (a run, or a ``baseline.measure`` idle window) starts at a poll: the cumulative energies and
the last sample time of every channel are taken there. It is asked to close at a *target* sample
time (the stop of a run; start + duration for an idle window), and it closes at the first poll at
which every DRAM channel has a sample ending at or after that target — so the energy a source books
at the stop (the sim adds the rest of a stopped run's traffic to the first sample ending after the
stop) is inside the window. A deadline on the monotonic clock closes it anyway if a channel stalls.

Each channel's window energy is the difference of the source's cumulative totals at the two polls
(exact: nothing is lost between polls), and its duration is the span of sample time between the
two polls' last samples (the source's own time: a sped-up sim's seconds, not the daemon's).

Example:
    >>> w = Window(kind="baseline", start_energy_j={"DDR_AB": 1.0}, start_t_ns={"DDR_AB": 0},
    ...            dram_channels=("DDR_AB",), t_start_mono_ns=0)
    >>> w.request_close(target_t_ns=20, deadline_mono_ns=100)
    >>> w.ready({"DDR_AB": 10}, now_mono_ns=5), w.ready({"DDR_AB": 20}, now_mono_ns=6)
    (False, True)
    >>> w.result({"DDR_AB": 3.0}, {"DDR_AB": 20}, now_mono_ns=6, speed=1.0)
    ({'DDR_AB': 2.0}, 2e-08, {'DDR_AB': 2e-08})
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hdeem_watch.daemon.runs import MAX_RUN_SAMPLES, window_energy


@dataclass
class Window:
    """One measurement window.

    Attributes:
        kind: ``"run"`` or ``"baseline"``.
        start_energy_j: cumulative energy per channel at the start poll.
        start_t_ns: last sample time per channel at the start poll (None = no sample yet).
        dram_channels: the channels whose samples decide when the window closes.
        t_start_mono_ns: monotonic time of the start poll.
        target_t_ns: sample time at which the window may close (None = still open).
        deadline_mono_ns: the window closes at this monotonic time whatever the samples say.
        context: what the owner needs when the window closes (run record, pending reply, ...).
    """

    kind: str
    start_energy_j: dict[str, float]
    start_t_ns: dict[str, int | None]
    dram_channels: tuple[str, ...]
    t_start_mono_ns: int
    target_t_ns: int | None = None
    deadline_mono_ns: int | None = None
    context: dict[str, Any] = field(default_factory=dict)
    samples: dict[str, list[np.ndarray]] = field(default_factory=dict)
    _counts: dict[str, int] = field(default_factory=dict)

    @property
    def closing(self) -> bool:
        """Whether a close was requested."""
        return self.target_t_ns is not None

    def request_close(self, *, target_t_ns: int, deadline_mono_ns: int) -> None:
        """Close at the first poll whose DRAM samples reach ``target_t_ns`` (or at the deadline)."""
        self.target_t_ns = int(target_t_ns)
        self.deadline_mono_ns = int(deadline_mono_ns)

    def ready(self, last_t_ns: Mapping[str, int | None], now_mono_ns: int) -> bool:
        """Whether the window can close now."""
        if self.target_t_ns is None:
            return False
        if self.deadline_mono_ns is not None and now_mono_ns >= self.deadline_mono_ns:
            return True
        channels = self.dram_channels or tuple(last_t_ns)
        return all((last_t_ns.get(c) or -1) >= self.target_t_ns for c in channels)

    def add_samples(self, channel: str, power_w: np.ndarray) -> None:
        """Keep a channel's samples (up to :data:`MAX_RUN_SAMPLES`), for the window's spread."""
        count = self._counts.get(channel, 0)
        if count >= MAX_RUN_SAMPLES or power_w.size == 0:
            return
        kept = np.array(power_w[: MAX_RUN_SAMPLES - count], dtype=float)
        self.samples.setdefault(channel, []).append(kept)
        self._counts[channel] = count + kept.size

    def channel_samples(self, channel: str) -> np.ndarray:
        """Every kept sample of ``channel``."""
        parts = self.samples.get(channel)
        return np.concatenate(parts) if parts else np.empty(0)

    def result(
        self,
        stop_energy_j: Mapping[str, float],
        stop_t_ns: Mapping[str, int | None],
        *,
        now_mono_ns: int,
        speed: float,
    ) -> tuple[dict[str, float], float, dict[str, float]]:
        """``(energy per channel, window_s, window_s per channel)`` at the closing poll.

        ``window_s`` is the DRAM channels' sample-time span; a channel without samples at either
        end falls back to the monotonic span times ``speed``.
        """
        energy = window_energy(self.start_energy_j, stop_energy_j)
        mono_s = (now_mono_ns - self.t_start_mono_ns) / 1e9 * speed
        spans: dict[str, float] = {}
        for name in energy:
            a, b = self.start_t_ns.get(name), stop_t_ns.get(name)
            spans[name] = (b - a) / 1e9 if a is not None and b is not None and b > a else mono_s
        dram = [spans[c] for c in self.dram_channels if c in spans]
        window_s = max(dram) if dram else mono_s
        return energy, float(window_s), spans


def mean_power(energy_j: Mapping[str, float], spans_s: Mapping[str, float]) -> dict[str, float]:
    """Energy over duration per channel (NaN where the duration is not positive)."""
    return {c: (e / spans_s[c] if spans_s.get(c, 0) > 0 else math.nan) for c, e in energy_j.items()}
