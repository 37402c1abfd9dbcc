"""Counter deltas per channel over each run and job window, next to the window's energy (pure, no I/O).

The poll loop hands every counter snapshot to :meth:`CounterWindows.observe` and asks
:meth:`CounterWindows.due` whether to read the counters now: at the heartbeat (for the stream's
command rates), while a run window has no start yet, and while a closing window's end lies past
the newest snapshot. Control operations read them at the window edges too (the poll just before a
run starts or stops), so a window's ends are counted where its energy is cut.

:meth:`CounterWindows.track` gives each new run window its start (the snapshot at the window's start,
interpolated between reads); :meth:`CounterWindows.finish` takes the closed run's end on the power
samples' axis (the last sample of its DRAM channels) and attaches the per-channel role deltas to
the run record (``record.counters``); :meth:`CounterWindows.finish_window` does the same for a job
segment's window (keyed by :func:`window_key`), and :meth:`CounterWindows.so_far` counts an open
one up to the newest read. From these counts the model makes the window's ``CommandStats``
(:func:`hdeem_watch.calibrate.run_model.counter_groups`).

Example:
    >>> from hdeem_watch.counters.source import CounterSnapshot
    >>> windows = CounterWindows("sim", table_key="haswell-ep", ranks=2, refresh_complete=False,
    ...                          sensors={"S0.imc0": "DDR_AB"}, heartbeat_ns=10)
    >>> windows.observe(CounterSnapshot(0, {"S0.imc0": {"act": 0.0, "cas_rd": 0.0}}), now_mono_ns=0)
    >>> windows.observe(CounterSnapshot(10**9, {"S0.imc0": {"act": 5e6, "cas_rd": 2e7}}), now_mono_ns=10**9)
    >>> windows.rates()["S0.imc0"]["act_per_s"]
    5000000.0
"""

from __future__ import annotations

import collections
import math
from collections.abc import Callable, Iterable, Mapping
from typing import Any, Protocol, runtime_checkable

from hdeem_watch.counters.source import CounterSnapshot, interpolate, window_counts

#: Snapshots kept to interpolate window ends (a few heartbeats and edge reads).
HISTORY = 16


@runtime_checkable
class ExactCounters(Protocol):
    """A counter source that knows its counts at an exact time on the samples' axis (the sim's):
    a window's edges are read there instead of interpolated between two reads."""

    def read_at(self, t_ns: int) -> CounterSnapshot | None:
        """The counts at exactly ``t_ns``, or None when not known (yet or any more)."""
        ...


def window_key(window: Any) -> str | None:
    """The key of a window's counter start: a run's id, ``job:<id>:<start poll>`` for a job segment
    (one per daemon session: the start poll's monotonic ns tells a requeued job's windows apart);
    None for other windows (baselines).

    >>> from types import SimpleNamespace as W
    >>> window_key(W(run=None, job_id="42", t_start_mono_ns=7)), window_key(W(run=None, job_id=None))
    ('job:42:7', None)
    """
    run = getattr(window, "run", None)
    if run is not None:
        return str(run.run_id)
    job_id = getattr(window, "job_id", None)
    if job_id is not None:
        return f"job:{job_id}:{int(window.t_start_mono_ns)}"
    return None


class CounterWindows:
    """Counter snapshots, run-window starts and the command rates of one node.

    Args:
        kind: the counter source's kind (``sim``, ``perf``, ``replay``).
        table_key: the event table's generation key.
        ranks: ranks per channel.
        refresh_complete: whether the refresh events count every refresh.
        sensors: channel → the DRAM power channel that measures it.
        heartbeat_ns: read at least this often (monotonic ns).
    """

    def __init__(self, kind: str, *, table_key: str, ranks: int, refresh_complete: bool,
                 sensors: Mapping[str, str | None], heartbeat_ns: int = 1_000_000_000) -> None:
        self.kind = kind
        self.table_key = table_key
        self.ranks = int(ranks)
        self.refresh_complete = bool(refresh_complete)
        self.sensors = dict(sensors)
        self.heartbeat_ns = int(heartbeat_ns)
        self.history: collections.deque[CounterSnapshot] = collections.deque(maxlen=HISTORY)
        self.error: str | None = None
        self._last_read_mono: int | None = None
        self._rate_base: CounterSnapshot | None = None
        self._rate_top: CounterSnapshot | None = None
        #: window key (:func:`window_key`) → the counters at its window's start.
        self._starts: dict[str, CounterSnapshot] = {}

    # -- reading ---------------------------------------------------------------------------------

    def due(self, now_mono_ns: int, windows: Iterable[Any] = ()) -> bool:
        """Whether to read the counters now (heartbeat, an untracked run window, a closing window's end)."""
        if self._last_read_mono is None or now_mono_ns - self._last_read_mono >= self.heartbeat_ns:
            return True
        newest = self.history[-1].t_ns if self.history else None
        for window in windows:
            key = window_key(window)
            if key is None:
                continue
            if key not in self._starts:
                return True
            target = getattr(window, "target_t_ns", None)
            if target is not None and (newest is None or newest < target):
                return True
        return False

    def observe(self, snapshot: CounterSnapshot, *, now_mono_ns: int) -> None:
        """Take a snapshot (time-ordered: an older one than the newest is ignored)."""
        self._last_read_mono = int(now_mono_ns)
        self.error = None
        if self.history and snapshot.t_ns < self.history[-1].t_ns:
            return
        self.history.append(snapshot)
        if self._rate_top is None or snapshot.t_ns - self._rate_top.t_ns >= 0.5e9:
            self._rate_base, self._rate_top = self._rate_top, snapshot

    def failed(self, error: BaseException, *, now_mono_ns: int) -> None:
        """A read failed: keep the reason (in the status), try again at the next heartbeat."""
        self._last_read_mono = int(now_mono_ns)
        self.error = f"{type(error).__name__}: {error}"

    # -- windows ---------------------------------------------------------------------------------

    def track(self, windows: Iterable[Any], sample_time: Callable[[int], int],
              exact: Callable[[int], CounterSnapshot | None] | None = None) -> None:
        """Give every new run or job window its start: the counters at its start poll (``exact`` when
        the source can count at any time it knows, else interpolated between reads)."""
        if not self.history:
            return
        for window in windows:
            key = window_key(window)
            if key is not None and key not in self._starts:
                t_ns = sample_time(window.t_start_mono_ns)
                start = exact(t_ns) if exact is not None else None
                self._starts[key] = start if start is not None else interpolate(self.history, t_ns)

    def finish(self, record: Any, dram_channels: Iterable[str],
               exact: Callable[[int], CounterSnapshot | None] | None = None) -> dict[str, Any] | None:
        """The counters of a closed run (``record.counters``), or None without a start or snapshot."""
        return self.finish_window(str(record.run_id), record.samples_ns, dram_channels, exact)

    def finish_window(self, key: str, samples_ns: Mapping[str, Any] | None, dram_channels: Iterable[str],
                      exact: Callable[[int], CounterSnapshot | None] | None = None) -> dict[str, Any] | None:
        """The counters of a closed window (run or job segment), cut where its DRAM samples end
        (``samples_ns``: channel → ``[first, last]`` sample time; counted there ``exact``ly when the
        source can); None without a start or snapshot."""
        start = self._starts.pop(key, None)
        if start is None or not self.history:
            return None
        wanted = set(dram_channels)
        ends = [span[1] for c, span in (samples_ns or {}).items() if c in wanted and span and span[1] is not None]
        end_t = max(ends) if ends else self.history[-1].t_ns
        status = "ok"
        end = exact(end_t) if exact is not None else None  # a source that counts at any time: to the sample
        if end is None and end_t > self.history[-1].t_ns:
            status = f"short: the counters reach {(end_t - self.history[-1].t_ns) / 1e9:.3f} s less far than the samples"
            end_t = self.history[-1].t_ns
        end = end if end is not None else interpolate(self.history, end_t)
        window_s = (end.t_ns - start.t_ns) / 1e9
        if not window_s > 0:
            return {"source": self.kind, "status": "unknown: empty counter window", "window_s": window_s}
        return self._record(start, end, status)

    def so_far(self, key: str) -> dict[str, Any] | None:
        """The counters of an open window up to the newest snapshot (``open: true``; None without a
        start); the window's start is kept."""
        start = self._starts.get(key)
        if start is None or not self.history or self.history[-1].t_ns <= start.t_ns:
            return None
        return self._record(start, self.history[-1], "ok", open=True)

    def _record(self, start: CounterSnapshot, end: CounterSnapshot, status: str, **extra: Any) -> dict[str, Any]:
        """A window's counters record from its start and end snapshots."""
        return {"source": self.kind, "generation": self.table_key, "status": status, **extra, "ranks": self.ranks,
                "refresh_complete": self.refresh_complete, "t_start_ns": start.t_ns, "t_end_ns": end.t_ns,
                "window_s": (end.t_ns - start.t_ns) / 1e9, "sensors": dict(self.sensors),
                "channels": window_counts(start, end)}

    def forget(self, key: str) -> None:
        """Drop a window's start (an aborted run, a job closed without its window)."""
        self._starts.pop(key, None)

    # -- rates -----------------------------------------------------------------------------------

    def rates(self) -> dict[str, dict[str, float]]:
        """Per channel over the latest ≥ 0.5 s between reads: ACT/s, RD/s, WR/s, power-down share
        (NaN where unknown); empty before two reads."""
        base, top = self._rate_base, self._rate_top
        if base is None or top is None or top.t_ns <= base.t_ns:
            return {}
        seconds = (top.t_ns - base.t_ns) / 1e9
        out = {}
        for channel, counts in window_counts(base, top).items():
            dclk = counts.get("dclk", math.nan)
            cke = [counts.get(f"cke_on_rank{r}", math.nan) for r in range(self.ranks)]
            if all(math.isfinite(c) for c in cke) and dclk > 0:
                powerdown = 1.0 - sum(cke) / (len(cke) * dclk)
            elif math.isfinite(counts.get("ppd_cycles", math.nan)) and dclk > 0:
                powerdown = counts["ppd_cycles"] / dclk
            else:
                powerdown = math.nan
            out[channel] = {"act_per_s": counts.get("act", math.nan) / seconds,
                            "rd_per_s": counts.get("cas_rd", math.nan) / seconds,
                            "wr_per_s": counts.get("cas_wr", math.nan) / seconds,
                            "powerdown_share": min(1.0, max(0.0, powerdown)) if math.isfinite(powerdown) else math.nan}
        return out
