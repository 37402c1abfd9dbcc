"""How often the daemon polls its source: full rate while someone watches, rarely while nobody does.

A compute node's daemon must not steal the node from the jobs it measures. Live rate matters only
while a subscriber takes the stream or a run or baseline window needs its edges; otherwise the
daemon polls each source at the slowest rate that loses nothing — its
:class:`~hdeem_watch.sources.base.QuietLimit` (a sensor buffer's depth, a counter's wrap time) with
a margin, converted from the source's time to the daemon's — and energies stay exact across the
gaps because sources report cumulative energy. A window opened while the daemon is quiet is exact
too: every window edge polls the source at once (the operations' edge poll), which returns the
buffered samples up to the edge.

:class:`PollPolicy` is pure: the shell (:mod:`hdeem_watch.daemon.shell.service`) asks it for the period
whenever a subscription, a window or a job changes.

Example:
    >>> from hdeem_watch.sources.base import QuietLimit
    >>> policy = PollPolicy(fast_s=0.04, idle_s=0.25, limit=QuietLimit(60.0), checkpoint_s=5.0)
    >>> policy.interval_s(PollDemand(watched=True, listening=True))
    0.04
    >>> policy.interval_s(PollDemand())            # nobody watches: half the 60 s buffer
    30.0
    >>> policy.interval_s(PollDemand(listening=True)), policy.interval_s(PollDemand(jobs_open=True))
    (1.0, 5.0)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hdeem_watch.sources.base import QuietLimit

__all__ = ["QUIET_MARGIN", "QUIET_MAX_S", "PollDemand", "PollPolicy"]

#: The share of a source's quiet limit the daemon uses: a poll delayed by a loaded machine (or a
#: stopped process) by as much again still loses nothing.
QUIET_MARGIN = 0.5
#: The longest quiet period whatever the source (s, daemon time): bounds one poll's batch, the age
#: of what a Prometheus scrape reads and of the last status a late subscriber finds.
QUIET_MAX_S = 30.0


@dataclass(frozen=True)
class PollDemand:
    """What asks for polls now.

    Attributes:
        watched: a subscriber takes samples (the XPUB socket saw its subscription): full rate.
        listening: some subscriber is connected (e.g. to ``status`` alone): polls at least every
            heartbeat, so that the status it receives is current.
        window_open: a run or baseline window is open (its live status, the sim's run traffic).
        jobs_open: a job window is open (its energy so far is checkpointed).
    """

    watched: bool = False
    listening: bool = False
    window_open: bool = False
    jobs_open: bool = False

    @property
    def live(self) -> bool:
        """Whether the stream must be live (full rate)."""
        return self.watched or self.window_open


@dataclass(frozen=True)
class PollPolicy:
    """The poll period for a :class:`PollDemand`.

    Args:
        fast_s: the full-rate period (``poll_interval_s``).
        idle_s: the quiet period of a source that states no :class:`QuietLimit`
            (``idle_poll_interval_s``; 0 = always full rate).
        limit: the source's quiet limit (None = it states none).
        speed: source seconds per daemon second (a sped-up sim fills its buffer faster).
        heartbeat_s: the status period (the longest period while someone listens).
        checkpoint_s: the job checkpoint period (the longest period while a job is open).
        max_s: the longest quiet period (:data:`QUIET_MAX_S`).
    """

    fast_s: float
    idle_s: float
    limit: QuietLimit | None = None
    speed: float = 1.0
    heartbeat_s: float = 1.0
    checkpoint_s: float = math.inf
    max_s: float = QUIET_MAX_S

    def quiet_s(self) -> float:
        """The period while nobody listens and nothing is open (never below ``fast_s``)."""
        if self.idle_s <= 0:
            return self.fast_s
        if self.limit is None:
            quiet = self.idle_s
        else:
            quiet = QUIET_MARGIN * self.limit.max_s / self.speed
        return max(self.fast_s, min(quiet, self.max_s))

    def interval_s(self, demand: PollDemand) -> float:
        """The poll period now."""
        if demand.live:
            return self.fast_s
        period = self.quiet_s()
        if demand.listening:
            period = min(period, self.heartbeat_s)
        if demand.jobs_open:
            period = min(period, self.checkpoint_s)
        return max(self.fast_s, period)

    def interval_ns(self, demand: PollDemand) -> int:
        """:meth:`interval_s` in integer ns (the loop's timers)."""
        return round(self.interval_s(demand) * 1e9)
