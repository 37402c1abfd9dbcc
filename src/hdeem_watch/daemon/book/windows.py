"""Measurement windows on the stream of polls: open, closing, closed.

A window (a run, a ``baseline.measure`` idle window, or a SLURM job's window) starts at a poll: the cumulative energy and
the last sample time of every channel are taken there. It is asked to close at a *target* on the
source's sample-time axis (the stop of a run; start + duration for an idle window). From then on
each channel is cut at the target as its samples arrive: the last sample kept is the one whose
interval contains the target (a sample at ``t`` covers ``(t − period, t]``; the sim books the rest
of a stopped run's energy into exactly that sample), and the energy of the samples after it is
taken back out of the channel's cumulative total — so the window is ``[start, stop]`` even when the
source delivers the samples around the stop late and in one batch. The window closes when every
DRAM channel has been cut, or at a deadline on the monotonic clock (a stalled channel then counts
what it delivered).

Each channel's window energy is the difference of the source's cumulative totals (exact: nothing is
lost between polls), and its duration the span of its sample times (the source's own time: a
sped-up sim's seconds, not the daemon's).

Example:
    >>> import numpy as np
    >>> w = Window(kind="baseline", start_energy_j={"DDR_AB": 1.0}, start_t_ns={"DDR_AB": 0},
    ...            dram_channels=("DDR_AB",), t_start_mono_ns=0)
    >>> w.request_close(target_t_ns=25, deadline_mono_ns=100, rates_hz={"DDR_AB": 1e8})
    >>> w.observe("DDR_AB", np.array([10, 20]), np.array([1e8, 1e8]), energy_j=3.0)
    >>> w.ready(now_mono_ns=5)
    False
    >>> w.observe("DDR_AB", np.array([30, 40]), np.array([1e8, 1e8]), energy_j=5.0)
    >>> w.ready(now_mono_ns=6)
    True
    >>> w.result({"DDR_AB": 5.0}, {"DDR_AB": 40}, now_mono_ns=6, speed=1.0)
    ({'DDR_AB': 3.0}, 3e-08, {'DDR_AB': 3e-08})
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from hdeem_watch.daemon.book.runs import MAX_RUN_SAMPLES, window_energy
from hdeem_watch.run_record import RunRecord

WindowKind = Literal["run", "baseline", "job"]


@dataclass
class Window:
    """One measurement window.

    Attributes:
        kind: ``"run"``, ``"baseline"`` or ``"job"``.
        start_energy_j: cumulative energy per channel at the start poll.
        start_t_ns: last sample time per channel at the start poll (None = no sample yet).
        dram_channels: the channels whose cut decides when the window closes.
        t_start_mono_ns: monotonic time of the start poll.
        target_t_ns: the end on the sample-time axis (None = still open).
        deadline_mono_ns: the window closes at this monotonic time whatever the samples say.
        run: the run's record (``kind == "run"``), as it was started.
        abort: the run was stopped with ``abort`` (its window is not modelled).
        cut: per channel, ``(cumulative energy at the end, time of the last sample kept)`` once the
            channel's samples have reached the target.
        job_id: the job's id (``kind == "job"``).
        keep_samples: keep the samples (for the spread of a baseline); a job window, which may last
            days, keeps only each channel's peak (``peak_w``).
        peak_w: per channel, the highest finite sample inside the window (only without
            ``keep_samples``).
    """

    kind: WindowKind
    start_energy_j: dict[str, float]
    start_t_ns: dict[str, int | None]
    dram_channels: tuple[str, ...]
    t_start_mono_ns: int
    target_t_ns: int | None = None
    deadline_mono_ns: int | None = None
    run: RunRecord | None = None
    abort: bool = False
    job_id: str | None = None
    keep_samples: bool = True
    peak_w: dict[str, float] = field(default_factory=dict)
    samples: dict[str, list[np.ndarray]] = field(default_factory=dict)
    cut: dict[str, tuple[float, int]] = field(default_factory=dict)
    _counts: dict[str, int] = field(default_factory=dict)
    _periods_ns: dict[str, float] = field(default_factory=dict)
    _last_t_ns: dict[str, int] = field(default_factory=dict)
    #: Per channel ``(last sample time before the window, last sample time in it)``, set by result().
    sample_spans_ns: dict[str, tuple[int | None, int | None]] = field(default_factory=dict)

    @property
    def closing(self) -> bool:
        """Whether a close was requested."""
        return self.target_t_ns is not None

    def request_close(self, *, target_t_ns: int, deadline_mono_ns: int, rates_hz: Mapping[str, float],
                      last_t_ns: Mapping[str, int | None] | None = None,
                      energy_j: Mapping[str, float] | None = None) -> None:
        """End the window at ``target_t_ns`` (sample time), or at ``deadline_mono_ns`` at the latest.

        ``last_t_ns``/``energy_j`` (the channels' state now) cut at once the channels that are
        already past the target (nothing of theirs can be taken back).
        """
        self.target_t_ns = int(target_t_ns)
        self.deadline_mono_ns = int(deadline_mono_ns)
        self._periods_ns = {c: 1e9 / r for c, r in rates_hz.items() if r > 0}
        for channel, t in (last_t_ns or {}).items():
            if t is not None and t >= self.target_t_ns and energy_j is not None:
                self.cut[channel] = (float(energy_j.get(channel, math.nan)), int(t))

    def observe(self, channel: str, t_ns: np.ndarray, power_w: np.ndarray, *, energy_j: float) -> None:
        """Take one batch of a channel (after the source's cumulative ``energy_j`` includes it)."""
        if self.kind == "job" and self.start_t_ns.get(channel) is None and t_ns.size and self.target_t_ns is None:
            # A job window opened before the channel's first sample (a job resumed at the daemon's
            # start) begins after the channel's first batch: exact from there on, never NaN for good.
            self.start_t_ns[channel] = int(t_ns[-1])
            self.start_energy_j[channel] = float(energy_j)
            return
        if self.target_t_ns is None or channel in self.cut:
            self.add_samples(channel, power_w)
            if t_ns.size:
                self._last_t_ns[channel] = int(t_ns[-1])
            return
        if t_ns.size == 0:
            return
        period = self._periods_ns.get(channel)
        if int(t_ns[-1]) < self.target_t_ns or period is None:
            self.add_samples(channel, power_w)
            self._last_t_ns[channel] = int(t_ns[-1])
            if period is None and int(t_ns[-1]) >= self.target_t_ns:
                self.cut[channel] = (float(energy_j), int(t_ns[-1]))
            return
        # Keep the samples whose interval starts before the target; take the rest back out.
        keep = t_ns < self.target_t_ns + period
        excess = float(np.sum(power_w[~keep])) * period * 1e-9
        kept_t = t_ns[keep]
        if not math.isfinite(excess):  # an unknown value after the stop: the total cannot be split
            self.cut[channel] = (float(energy_j), int(t_ns[-1]))
            self.add_samples(channel, power_w)
            return
        self.add_samples(channel, power_w[keep])
        end = int(kept_t[-1]) if kept_t.size else self._last_t_ns.get(channel, self.start_t_ns.get(channel) or 0)
        self.cut[channel] = (float(energy_j) - excess, end)

    def ready(self, now_mono_ns: int) -> bool:
        """Whether the window can close now."""
        if self.target_t_ns is None:
            return False
        if self.deadline_mono_ns is not None and now_mono_ns >= self.deadline_mono_ns:
            return True
        return all(c in self.cut for c in self.dram_channels)

    def add_samples(self, channel: str, power_w: np.ndarray) -> None:
        """Keep a channel's samples (up to :data:`MAX_RUN_SAMPLES`), for the window's spread; without
        ``keep_samples`` only its peak."""
        if not self.keep_samples:
            if power_w.size:
                peak = _finite_max(power_w)
                if peak > self.peak_w.get(channel, -math.inf):
                    self.peak_w[channel] = peak
            return
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
        energy_now_j: Mapping[str, float],
        last_t_now_ns: Mapping[str, int | None],
        *,
        now_mono_ns: int,
        speed: float,
    ) -> tuple[dict[str, float], float, dict[str, float]]:
        """``(energy per channel, window_s, window_s per channel)`` when the window closes.

        Cut channels use their cut; the others (deadline) what they have now. ``window_s`` is the
        DRAM channels' longest span; a channel without samples falls back to the monotonic span
        times ``speed``.
        """
        stop_energy = {c: self.cut[c][0] if c in self.cut else e for c, e in energy_now_j.items()}
        stop_t = {c: self.cut[c][1] if c in self.cut else t for c, t in last_t_now_ns.items()}
        energy = window_energy(self.start_energy_j, stop_energy)
        mono_s = (now_mono_ns - self.t_start_mono_ns) / 1e9 * speed
        spans: dict[str, float] = {}
        for name in energy:
            a, b = self.start_t_ns.get(name), stop_t.get(name)
            spans[name] = (b - a) / 1e9 if a is not None and b is not None and b > a else mono_s
        dram = [spans[c] for c in self.dram_channels if c in spans]
        window_s = max(dram) if dram else mono_s
        self.sample_spans_ns = {c: (self.start_t_ns.get(c), stop_t.get(c)) for c in energy}
        return energy, float(window_s), spans


def _finite_max(values: np.ndarray) -> float:
    """The largest finite value (-inf when there is none)."""
    peak = float(np.max(values))
    if math.isfinite(peak):
        return peak
    finite = values[np.isfinite(values)]
    return float(np.max(finite)) if finite.size else -math.inf


def mean_power(energy_j: Mapping[str, float], spans_s: Mapping[str, float]) -> dict[str, float]:
    """Energy over duration per channel (NaN where the duration is not positive)."""
    return {c: (e / spans_s[c] if spans_s.get(c, 0) > 0 else math.nan) for c, e in energy_j.items()}
