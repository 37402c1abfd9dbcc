"""A SLURM job's whole life in the daemon without sockets: job.start → windows → job.stop → record.

The run book, the job book and the job ops run on a fake monotonic and wall clock with a small fake
DRAM node (four channels at 100 Sa/s); the database is a real SQLite file on the real store worker
thread; the publisher is a recorder. Every sample the source delivered is kept, so each record's
energy is checked against an independent integral of those samples over the record's sample spans.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hdeem_watch.daemon.book import baselines as bl
from hdeem_watch.daemon.book.runs import parse_run_args
from hdeem_watch.daemon.book.state import NodeState
from hdeem_watch.daemon.compose import NodePorts, build_node
from hdeem_watch.daemon.ops.jobs import unfinished_jobs
from hdeem_watch.daemon.ops.reporting import Identity
from hdeem_watch.daemon.shell.control import OpError, Pending
from hdeem_watch.daemon.shell.workers import Worker
from hdeem_watch.daemon.store.database import Store
from hdeem_watch.daemon.store.worker import StoreWorker
from hdeem_watch.sources.base import ChannelInfo, SourceBatch
from hdeem_watch.wire.protocol import ProtocolError

DRAM = ("DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH")
PERIOD_NS = 10_000_000  # 100 Sa/s
POLL_NS = 40_000_000
WALL0 = 1_700_000_000 * 10**9


class FakeDram:
    """Four DRAM channels: power steps with the sample index (1..7 W, so peaks and sums are not
    trivial); sample time = monotonic time; cumulative energy = the sum of the samples × period."""

    def __init__(self, clock: Any, energy0: float = 0.0) -> None:
        self.clock = clock
        self.k = clock() // PERIOD_NS
        self.energy = dict.fromkeys(DRAM, energy0)
        self.seen: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {c: [] for c in DRAM}

    def channels(self) -> list[ChannelInfo]:
        return [ChannelInfo(name, 100.0, "dram") for name in DRAM]

    def poll(self) -> SourceBatch:
        now = self.clock()
        last = now // PERIOD_NS
        t = np.arange(self.k + 1, last + 1, dtype=np.int64) * PERIOD_NS
        self.k = last
        samples = {}
        for i, name in enumerate(DRAM):
            p = 1.0 + ((t // PERIOD_NS + i) % 7).astype(float)
            self.energy[name] += float(p.sum()) * PERIOD_NS / 1e9
            samples[name] = (t, p)
            self.seen[name].append((t, p))
        return SourceBatch(now, now, samples, dict(self.energy), dict.fromkeys(DRAM, "ok"))

    def integral(self, channel: str, first: int | None, last: int | None) -> float:
        """Energy of the samples with first < t <= last (independent of the daemon's bookkeeping)."""
        t = np.concatenate([a for a, _ in self.seen[channel]])
        p = np.concatenate([b for _, b in self.seen[channel]])
        inside = (t > (first if first is not None else -1)) & (t <= (last if last is not None else -1))
        return float(p[inside].sum()) * PERIOD_NS / 1e9


class Recorder:
    def __init__(self) -> None:
        self.messages: list[tuple[str, dict[str, Any]]] = []

    def publish(self, kind: str, body: Any, /) -> bool:
        self.messages.append((kind, dict(body)))
        return True


class JobNode:
    """The job book and ops of one node over a real store, on a fake clock (no sockets)."""

    def __init__(self, state_dir: Path, now: int = 1_000 * PERIOD_NS, checkpoint_s: float = 1.0) -> None:
        self.now = now
        self.source = FakeDram(lambda: self.now)
        self.store = Store(state_dir / "state.db")
        self.book = NodeState(self.source.channels(), node="n1", monotonic=lambda: self.now, wall=self.wall)
        self.writer = StoreWorker(self.store)
        self.publisher = Recorder()
        self.replies: dict[int, tuple[Any, tuple[str, str] | None]] = {}
        self.models = Worker("model")  # models a job from its counters; these jobs have none
        ports = NodePorts(store=self.writer, submit=self.models.submit, publisher=self.publisher, reply=self.reply,
                          poll=self.poll)
        self.core = build_node(self.book, self.source, lambda: self.now, ports,
                               identity=Identity(kind="fake", endpoints={}), poll_interval_ns=lambda: POLL_NS,
                               checkpoint_s=checkpoint_s)
        self.ops = self.core.job_ops
        self.poll()
        self.ops.resume(unfinished_jobs(self.store))

    def wall(self) -> int:
        return WALL0 + self.now

    def reply(self, pending: Pending, result: Any, error: tuple[str, str] | None) -> None:
        self.replies[id(pending)] = (result, error)

    def poll(self) -> None:
        _fresh, closed = self.book.on_batch(self.source.poll())
        for window in closed:
            self.core.window_closed(window)

    def advance(self, seconds: float) -> None:
        for _ in range(round(seconds * 1e9 / POLL_NS)):
            self.now += POLL_NS
            self.poll()
            self.ops.checkpoint()

    def settle(self) -> None:
        while self.writer.pending:
            for future, _done, _failed in list(self.writer.jobs.pending):
                future.exception(timeout=30)
            self.writer.collect()

    def call(self, op: str, args: dict[str, Any] | None = None) -> Any:
        try:
            result = self.ops.handlers()[op](args or {})
        except (OpError, ProtocolError) as error:
            raise Failed(error.code) from None
        if not isinstance(result, Pending):
            return result
        for _ in range(200):
            self.settle()
            if id(result) in self.replies:
                value, error = self.replies.pop(id(result))
                if error is not None:
                    raise Failed(error[0])
                return value
            self.advance(POLL_NS / 1e9)
        raise AssertionError(f"{op}: no reply")

    def crash(self) -> None:
        """What ``kill -9`` leaves: the written database; nothing else is closed or flushed."""
        self.store.flush()
        self.writer.jobs.worker.shutdown(wait=True)

    def close(self) -> None:
        self.models.shutdown(cancel_queued=True)
        self.writer.shutdown()
        self.store.close()


class Failed(Exception):
    def __init__(self, code: str) -> None:
        super().__init__(code)
        self.code = code


def assert_exact(node: JobNode, record: dict[str, Any]) -> None:
    """Each segment's energy per channel is the integral of the source's samples over its span."""
    for segment in record["segments"]:
        for channel, (first, last) in segment["samples_ns"].items():
            expected = node.source.integral(channel, first, last)
            assert segment["energy_j"][channel] == pytest.approx(expected, rel=1e-12, abs=1e-9), channel
    total = {c: sum(s["energy_j"][c] for s in record["segments"]) for c in DRAM}
    assert record["energy_j"] == pytest.approx(total, rel=1e-12)
    assert record["dram_energy_j"] == pytest.approx(sum(total.values()), rel=1e-12)


@pytest.fixture
def node(tmp_path: Path) -> Any:
    made = JobNode(tmp_path)
    yield made
    made.close()


def test_a_job_from_prolog_to_epilog(node: JobNode) -> None:
    """job.start opens a window beside runs (a run inside the job is not refused); job.stop closes it
    cut to the sample: energy = integral of the samples, peak, mean, duration, the stored record,
    job.get/job.list, the job topic and the owners' uids while it runs."""
    node.advance(0.5)
    started = node.call("job.start", {"job_id": "4242", "user": "alice", "uid": 1000, "nodes": ["n1"], "cpus": 4})
    assert started["state"] == "running" and started["job_id"] == "4242"
    assert node.ops.running_job_uids() == frozenset({1000})
    node.advance(1.0)
    run = node.book.start_run(parse_run_args({"kernel": "idle"}))  # a run inside a job: no conflict
    node.book.stop_run(run.run_id)
    node.advance(1.0)
    live = node.call("job.get", {"job_id": "4242"})
    assert live["state"] == "running" and live["dram_energy_j"] > 0
    assert_exact(node, live)
    node.advance(0.2)
    stopped = node.call("job.stop", {"job_id": 4242, "exit_code": "0"})
    assert stopped["state"] == "done" and stopped["exit_code"] == 0 and stopped["status"] == "ok"
    assert len(stopped["segments"]) == 1
    assert_exact(node, stopped)
    assert stopped["dram_energy_j"] > live["dram_energy_j"]
    first, last = stopped["segments"][0]["samples_ns"]["DDR_AB"]
    assert stopped["measured_s"] == pytest.approx((last - first) / 1e9)
    assert 2.2 <= stopped["measured_s"] <= 2.4 and stopped["duration_s"] == pytest.approx(stopped["measured_s"], abs=0.1)
    assert stopped["peak_power_w"] == dict.fromkeys(DRAM, 7.0)
    for c in DRAM:
        assert stopped["mean_power_w"][c] == pytest.approx(stopped["energy_j"][c] / stopped["measured_s"], rel=1e-6)
    assert node.ops.running_job_uids() == frozenset()
    assert node.call("job.stop", {"job_id": "4242"}) == stopped  # the Epilog retried: the same answer
    node.settle()
    assert node.call("job.get", {"job_id": "4242"})["dram_energy_j"] == stopped["dram_energy_j"]
    listed = node.call("job.list", {"user": "alice"})["jobs"]
    assert [j["job_id"] for j in listed] == ["4242"] and "segments" not in listed[0]
    assert node.call("job.list", {"user": "bob"})["jobs"] == []
    assert node.call("job.list", {"since_ns": node.wall() + 1})["jobs"] == []
    events = [(body["event"], body["job"]["job_id"]) for kind, body in node.publisher.messages if kind == "job"]
    assert events == [("start", "4242"), ("stop", "4242")]


def test_above_baseline_is_nan_without_a_baseline(node: JobNode) -> None:
    """Without an idle baseline the above-baseline energy is NaN with a status naming the channels,
    never 0; with one it is energy − baseline power × measured seconds."""
    node.call("job.start", {"job_id": "1"})
    node.advance(0.5)
    record = node.call("job.stop", {"job_id": "1"})
    assert all(math.isnan(v) for v in record["above_baseline_j"].values())
    assert math.isnan(record["dram_above_baseline_j"]) and record["baseline_status"].startswith("no baseline: DDR_AB")
    node.book.baselines = {c: bl.Baseline(3.0, 0.1, 100, 0, "measured") for c in DRAM}
    node.call("job.start", {"job_id": "2"})
    node.advance(0.5)
    record = node.call("job.stop", {"job_id": "2"})
    assert record["baseline_status"] == "ok"
    for c in DRAM:
        assert record["above_baseline_j"][c] == pytest.approx(record["energy_j"][c] - 3.0 * record["measured_s"])


def test_a_job_survives_kill_9(tmp_path: Path) -> None:
    """The daemon dies mid-job: the restarted daemon resumes the job in a new segment; the record
    keeps the energy up to the last checkpoint, marks the gap, and each segment is exact."""
    first = JobNode(tmp_path)
    first.call("job.start", {"job_id": "77", "user": "bob", "uid": 1001})
    first.advance(2.5)  # checkpoints every second
    first.settle()
    first.crash()
    second = JobNode(tmp_path, now=first.now + 3 * 10**9)  # down for 3 s
    try:
        assert second.ops.running_job_uids() == frozenset({1001})
        second.advance(1.0)
        record = second.call("job.stop", {"job_id": "77"})
        assert record["state"] == "done" and len(record["segments"]) == 2
        assert 3.0 <= record["unmeasured_s"] < 4.1 and record["status"].startswith("gap:")
        checkpointed = record["segments"][0]
        assert 1.7 <= checkpointed["spans_s"]["DDR_AB"] <= 2.5
        # Each session's source counts its energy afresh: each segment against its own session's samples.
        for channel, (a, b) in record["segments"][1]["samples_ns"].items():
            assert record["segments"][1]["energy_j"][channel] == pytest.approx(second.source.integral(channel, a, b))
        for channel, (a, b) in checkpointed["samples_ns"].items():
            assert checkpointed["energy_j"][channel] == pytest.approx(first.source.integral(channel, a, b))
        assert record["measured_s"] == pytest.approx(sum(s["spans_s"]["DDR_AB"] for s in record["segments"]))
    finally:
        second.close()


def test_a_stop_that_comes_after_the_daemon_was_down_closes_the_job_interrupted(tmp_path: Path) -> None:
    """The job ended while no daemon ran (the Epilog retried later with the end time): the job is
    closed as interrupted with what the first session measured; the later segment is dropped."""
    first = JobNode(tmp_path)
    first.call("job.start", {"job_id": "9"})
    first.advance(1.5)
    first.settle()
    first.crash()
    ended = first.wall() + 10**9
    second = JobNode(tmp_path, now=first.now + 5 * 10**9)
    try:
        second.advance(0.5)
        record = second.call("job.stop", {"job_id": "9", "ended_ns": ended})
        assert record["state"] == "interrupted" and len(record["segments"]) == 1
        last_checkpoint = record["segments"][0]["t_stop_ns"]
        assert record["t_stop_ns"] == ended and record["unmeasured_s"] == pytest.approx((ended - last_checkpoint) / 1e9)
        assert 1.0 <= record["unmeasured_s"] <= 2.0
        assert not second.book.windows
        second.settle()
        assert second.store.list_jobs(job_id="9")[0]["state"] == "interrupted"
    finally:
        second.close()


def test_overlapping_jobs_name_each_other_and_bad_requests_are_refused(node: JobNode) -> None:
    """Two jobs on a shared node each say they shared it; a repeated start changes nothing; bad
    arguments are bad-args, an unknown job not-found."""
    node.call("job.start", {"job_id": "1", "uid": 5})
    node.advance(0.2)
    again = node.call("job.start", {"job_id": "1", "uid": 5})
    assert again["state"] == "running" and len(node.book.windows) == 1
    node.call("job.start", {"job_id": "2", "uid": 6})
    assert node.ops.running_job_uids() == frozenset({5, 6})
    node.advance(0.2)
    one = node.call("job.stop", {"job_id": "1"})
    node.advance(0.2)
    two = node.call("job.stop", {"job_id": "2"})
    assert one["shared_with"] == ["2"] and two["shared_with"] == ["1"]
    for op, args in (("job.start", {}), ("job.start", {"job_id": "1 2"}), ("job.start", {"job_id": "3", "uid": -1}),
                     ("job.stop", {"job_id": "1", "exit_code": 1.5}), ("job.list", {"limit": 0})):
        with pytest.raises(Failed) as info:
            node.call(op, args)
        assert info.value.code == "bad-args", (op, args)
    for op in ("job.stop", "job.get"):
        with pytest.raises(Failed) as info:
            node.call(op, {"job_id": "404"})
        assert info.value.code == "not-found"


def test_a_late_stop_inside_the_session_says_how_late(node: JobNode) -> None:
    """A stop that comes after the job's end while the same daemon measured (it did not answer the
    Epilog in time): the window closes now and the record says how long past the end it measured."""
    node.call("job.start", {"job_id": "3"})
    node.advance(2.0)
    ended = node.wall() - 1_500_000_000
    record = node.call("job.stop", {"job_id": "3", "ended_ns": ended})
    assert record["state"] == "done" and record["late_stop_s"] == pytest.approx(1.5, abs=0.05)
    assert record["status"].startswith("late stop: measured 1.5 s past the job's end")
    assert_exact(node, record)


def test_a_clean_exit_stores_the_open_jobs_up_to_the_exit(tmp_path: Path) -> None:
    """The daemon's close forces a checkpoint: the stored record of an open job ends at the exit,
    whenever the last periodic checkpoint was."""
    node = JobNode(tmp_path, checkpoint_s=3600.0)
    try:
        node.call("job.start", {"job_id": "12"})
        node.advance(1.0)
        assert node.ops.checkpoint() == 0  # not due
        assert node.ops.checkpoint(force=True) == 1
        node.settle()
        stored = node.store.list_jobs(job_id="12", limit=1)[0]
        assert stored["state"] == "running" and stored["segments"][0]["open"]
        assert 0.9 <= stored["segments"][0]["spans_s"]["DDR_AB"] <= 1.0
        assert_exact(node, stored)
    finally:
        node.close()
