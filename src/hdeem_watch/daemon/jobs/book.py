"""The job book of one node: which SLURM jobs are open, and what their windows measured (pure).

:class:`JobBook` sits beside the run book (:class:`~hdeem_watch.daemon.book.state.NodeState`) and
uses its window machinery: each open job is one ``"job"`` :class:`~hdeem_watch.daemon.book.windows.Window`
in the run book, fed by every batch like a run window (so whatever a window integrates — energies,
and counters once they are windowed — a job gets too), but it blocks neither runs nor baselines and
keeps no samples (only each channel's peak). Several jobs may be open at once (a shared node); each
names the others it overlapped (``shared_with``): the node's DRAM energy cannot be split between
them. With counter windows (:class:`~hdeem_watch.daemon.counters.windows.CounterWindows`), each
segment also carries the memory controller's counts over its window (an open one up to the newest
counter read).

No I/O and no clock of its own: the shell (:mod:`hdeem_watch.daemon.ops.jobs`) stores the records
it returns. A job's life: :meth:`JobBook.start` → (batches) → :meth:`JobBook.checkpoint` every few
seconds (its energy so far, stored so that a crash loses at most that much) → :meth:`JobBook.stop`
→ the window closes after a batch → :meth:`JobBook.finished` gives the record. A daemon that
restarts :meth:`JobBook.resume`\\ s the jobs stored as running: a new segment, the gap marked.

Example:
    >>> import numpy as np
    >>> from hdeem_watch.daemon.book.state import NodeState
    >>> from hdeem_watch.daemon.jobs.records import parse_job_args
    >>> from hdeem_watch.sources.base import ChannelInfo, SourceBatch
    >>> now = [0]
    >>> book = NodeState([ChannelInfo("DDR_AB", 100.0, "dram")], node="n1", monotonic=lambda: now[0],
    ...                  wall=lambda: now[0])
    >>> def batch(k):  # the k-th 10 ms sample of 2 W
    ...     t = np.array([k * 10_000_000])
    ...     return SourceBatch(t[0], t[0], {"DDR_AB": (t, np.array([2.0]))}, {"DDR_AB": 0.02 * k}, {"DDR_AB": "ok"})
    >>> _ = book.on_batch(batch(1))
    >>> jobs = JobBook(book)
    >>> _ = jobs.start(parse_job_args({"job_id": "7", "uid": 1000}))
    >>> for k in range(2, 102):
    ...     now[0] = k * 10_000_000
    ...     _ = book.on_batch(batch(k))
    >>> jobs.running_job_uids()
    frozenset({1000})
    >>> _ = jobs.stop("7")
    >>> now[0] = 1_020_000_000
    >>> record = jobs.finished(book.on_batch(batch(102)).closed[0])
    >>> record.state, round(record.dram_energy_j, 6), record.peak_power_w
    ('done', 2.0, {'DDR_AB': 2.0})
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from dataclasses import dataclass

from hdeem_watch.daemon.book.runs import window_energy
from hdeem_watch.daemon.book.state import ClosedWindow, Conflict, NodeState
from hdeem_watch.daemon.book.windows import Window
from hdeem_watch.daemon.counters.windows import CounterWindows, window_key
from hdeem_watch.daemon.jobs.records import finish, with_segments
from hdeem_watch.job_record import JobArgs, JobRecord, Segment

#: Most jobs open at once on one node (beyond, ``job.start`` is refused: a Prolog storm or stale
#: jobs whose Epilog never reached the daemon).
MAX_OPEN_JOBS = 512


@dataclass
class _OpenJob:
    """An open job: its record (earlier segments included), its window and its exit code."""

    record: JobRecord
    window: Window
    t_segment_ns: int
    exit_code: int | str | None = None


def _spans(window: Window, stop_t_ns: dict[str, int | None]) -> tuple[dict[str, float], dict[str, list[int | None]]]:
    spans, samples = {}, {}
    for channel, stop in stop_t_ns.items():
        start = window.start_t_ns.get(channel)
        spans[channel] = (stop - start) / 1e9 if start is not None and stop is not None and stop > start else 0.0
        samples[channel] = [start, stop]
    return spans, samples


class JobBook:
    """The open jobs of one node, on the run book's windows.

    Args:
        book: the node's run book (its windows, clocks, channels and baselines).
        max_open: most jobs open at once.
        counters: the node's counter windows (None: counters off); each segment then carries the
            counts over its window.
    """

    def __init__(self, book: NodeState, *, max_open: int = MAX_OPEN_JOBS,
                 counters: CounterWindows | None = None) -> None:
        self.book = book
        self.max_open = max_open
        self.counters = counters
        self._open: dict[str, _OpenJob] = {}

    # -- queries ----------------------------------------------------------------------------------

    def running_job_uids(self) -> frozenset[int]:
        """The uids owning the jobs open on this node now (for the authorization of control ops)."""
        return frozenset(j.record.uid for j in self._open.values() if j.record.uid is not None)

    def is_open(self, job_id: str) -> bool:
        """Whether ``job_id`` is open here (closing included)."""
        return job_id in self._open

    def snapshot(self, job_id: str) -> JobRecord | None:
        """An open job's record with its energy so far (None when it is not open)."""
        job = self._open.get(job_id)
        if job is None:
            return None
        segments = list(job.record.segments)
        if not job.window.closing:
            segments.append(self._so_far(job))
        return self._totals(job.record, segments)

    def snapshots(self) -> list[JobRecord]:
        """Every open job with its energy so far, oldest first."""
        return [r for r in (self.snapshot(j) for j in self._open) if r is not None]

    # -- a job's life -----------------------------------------------------------------------------

    def start(self, args: JobArgs) -> tuple[JobRecord, bool]:
        """Open a job's window now (poll the source just before); ``(record, new)``.

        A job already open is not opened twice (a Prolog retried): its record comes back, ``new``
        False.

        Raises:
            Conflict: :data:`MAX_OPEN_JOBS` jobs are open.
        """
        known = self.snapshot(args.job_id)
        if known is not None:
            return known, False
        if len(self._open) >= self.max_open:
            raise Conflict(f"{len(self._open)} jobs are open on this node (the most is {self.max_open}); "
                           "stop finished ones with job.stop")
        record = JobRecord.start(args, node=self.book.node, t_wall_ns=self.book.wall())
        self._admit(record, fresh=True)
        return self.snapshot(args.job_id) or record, True

    def resume(self, stored: JobRecord) -> None:
        """Open a new segment of a job a previous daemon left running (its segments kept; an open
        one, its last checkpoint, counts as closed there; the time since is an unmeasured gap)."""
        if stored.job_id in self._open:
            return
        closed = tuple(dataclasses.replace(s, open=False) for s in stored.segments)
        self._admit(dataclasses.replace(stored, segments=closed), fresh=False)

    def _admit(self, record: JobRecord, *, fresh: bool) -> None:
        others = list(self._open)
        for other in others:
            job = self._open[other]
            job.record = job.record.sharing([record.job_id])
        window = self.book.open_job_window(record.job_id)
        # a resumed job: a gap since its last segment (a record read without its start has none)
        begin = record.t_start_ns if fresh and record.t_start_ns is not None else self.book.wall()
        self._open[record.job_id] = _OpenJob(record.sharing(others), window, t_segment_ns=begin)

    def stop(self, job_id: str, exit_code: int | str | None = None, *, ended_ns: int | None = None) -> JobRecord | None:
        """Ask an open job's window to close now; None while it closes (:meth:`finished` gives the
        record after a batch).

        ``ended_ns`` (wall clock) is when the job really ended, for a stop that comes late (an
        Epilog that could not reach the daemon retries later): when it lies before the current
        segment began, the job ended while no daemon measured it, and the job is closed at once as
        ``interrupted`` with what the earlier segments measured (the current segment measured time
        after the job and is dropped). When it lies inside the current segment the window closes now
        (its samples are not kept, so it cannot be cut back) and ``late_stop_s`` says by how much.

        Raises:
            KeyError: the job is not open.
        """
        job = self._open[job_id]
        job.exit_code = exit_code if exit_code is not None else job.exit_code
        if ended_ns is not None and ended_ns >= job.t_segment_ns:  # late: the samples since cannot be taken back
            late_s = max(0.0, (self.book.wall() - ended_ns) / 1e9)
            job.record = dataclasses.replace(job.record, late_stop_s=late_s if late_s >= 1.0 else 0.0)
        if ended_ns is not None and ended_ns < job.t_segment_ns:
            self._open.pop(job_id)
            self._forget_counters(job.window)
            if job.window in self.book.windows:
                self.book.windows.remove(job.window)
            return finish(job.record, state="interrupted", t_wall_ns=ended_ns, dram_channels=self.book.dram_channels,
                                     baselines_w=self._baselines_w(), exit_code=job.exit_code)
        self.book.close_job_window(job.window)
        return None

    def finished(self, closed: ClosedWindow) -> JobRecord:
        """The record of a job whose window closed (``done``), with every segment's totals."""
        window = closed.window
        assert window is not None and window.job_id is not None
        job = self._open.pop(window.job_id)
        stops = {c: span[1] for c, span in window.sample_spans_ns.items()}
        spans, samples = _spans(window, stops)
        now = self.book.wall()
        counters = None
        key = window_key(window)
        if self.counters is not None and key is not None:
            counters = self.counters.finish_window(key, samples, self.book.dram_channels)
        segment = Segment(t_start_ns=job.t_segment_ns, t_stop_ns=now, energy_j=dict(closed.energy_j),
                          spans_s=spans, samples_ns=samples, peak_w=dict(window.peak_w), counters=counters)
        record = dataclasses.replace(job.record, segments=(*job.record.segments, segment))
        return finish(record, state="done", t_wall_ns=now, dram_channels=self.book.dram_channels,
                             baselines_w=self._baselines_w(), exit_code=job.exit_code)

    def checkpoint(self) -> list[JobRecord]:
        """The open jobs' records with their energy so far (to store; closing ones are left out)."""
        return [self._totals(j.record, [*j.record.segments, self._so_far(j)])
                for j in self._open.values() if not j.window.closing]

    # -- helpers ----------------------------------------------------------------------------------

    def _so_far(self, job: _OpenJob) -> Segment:
        """The open segment up to the last batch: exact like a closed one (cumulative energies now)."""
        book, window = self.book, job.window
        spans, samples = _spans(window, book.last_sample_times())
        key = window_key(window)
        counters = self.counters.so_far(key) if self.counters is not None and key is not None else None
        return Segment(t_start_ns=job.t_segment_ns, t_stop_ns=book.wall(),
                       energy_j=window_energy(window.start_energy_j, book.energies()), spans_s=spans,
                       samples_ns=samples, peak_w=dict(window.peak_w), open=True, counters=counters)

    def _forget_counters(self, window: Window) -> None:
        key = window_key(window)
        if self.counters is not None and key is not None:
            self.counters.forget(key)

    def _baselines_w(self) -> dict[str, float]:
        return {c: b.power_w for c, b in self.book.baselines.items()}

    def _totals(self, record: JobRecord, segments: Iterable[Segment]) -> JobRecord:
        return with_segments(record, list(segments), dram_channels=self.book.dram_channels,
                                    baselines_w=self._baselines_w(), t_wall_ns=self.book.wall())
