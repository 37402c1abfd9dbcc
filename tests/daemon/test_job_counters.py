"""A SLURM job's memory-controller counts and its modelled DRAM energy by component (issues 17 + 18).

The pure cores on a fake clock: the run book (:class:`~hdeem_watch.daemon.book.state.NodeState`),
the job book and the counter windows fed fake batches and fake counter snapshots (cumulative counts
growing at fixed rates, as the IMC's free-running counters do), a daemon "killed" between two
segments (a new book resumes the checkpointed record), and the run modeller's
:meth:`~hdeem_watch.calibrate.run_model.RunModeller.model_counters` on the job's summed counts.
"""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from hdeem_watch.calibrate.counter_model import COMPONENT_KINDS
from hdeem_watch.calibrate.run_model import RunModeller
from hdeem_watch.counters.source import CounterSnapshot
from hdeem_watch.daemon.book.state import NodeState
from hdeem_watch.daemon.counters.windows import CounterWindows
from hdeem_watch.daemon.jobs.book import JobBook
from hdeem_watch.daemon.jobs.records import parse_job_args
from hdeem_watch.daemon.ops.jobs import MODELLING, JobOperations, unmodelled_jobs
from hdeem_watch.daemon.store.database import Store
from hdeem_watch.daemon.store.worker import StoreWorker
from hdeem_watch.dram.energy import COMPONENTS
from hdeem_watch.job_record import JobRecord
from hdeem_watch.sources.base import ChannelInfo, SourceBatch

# One worker runs the module, so its module-scoped fixture is built once, not once per worker.
pytestmark = pytest.mark.xdist_group("daemon-job_counters")

MEMSPEC = "samsung-m393a1g43db0-cpb"
PERIOD_NS = 10_000_000  # one batch (one 2 W sample per channel) every 10 ms
SENSORS = {"S0.imc0": "DDR_AB", "S0.imc1": "DDR_CD"}
#: Counts per second of each channel (the second channel carries half the traffic).
RATES = {"dclk": 1.0667e9, "cas_rd": 1e8, "cas_wr": 5e7, "act": 4e7, "pre_page_miss": 3e7,
         "pre_page_close": 1e7, "refresh": 0.0, "cke_on_rank0": 0.9e9, "cke_on_rank1": 0.9e9,
         "ppd_cycles": 0.0, "sref_cycles": 0.0}
SHARE = {"S0.imc0": 1.0, "S0.imc1": 0.5}


class FakeNode:
    """One daemon session: the run book, its job book and counter windows on a shared fake clock."""

    def __init__(self, clock: list[int], *, counters: bool = True) -> None:
        self.clock = clock
        channels = [ChannelInfo(name, 100.0, "dram") for name in SENSORS.values()]
        self.book = NodeState(channels, node="n1", monotonic=lambda: clock[0], wall=lambda: clock[0])
        self.windows = CounterWindows("sim", table_key="haswell-ep", ranks=2, refresh_complete=False,
                                      sensors=SENSORS, heartbeat_ns=PERIOD_NS) if counters else None
        self.jobs = JobBook(self.book, counters=self.windows)
        self.finished: list[JobRecord] = []
        self.on_closed: Any = None  # a closed job window's handler (default: keep the record)

    def step(self) -> None:
        """10 ms later: a batch, a counter read, job windows tracked and closed."""
        self.clock[0] += PERIOD_NS
        t = self.clock[0]
        times = np.array([t])
        energy = 2.0 * t / 1e9  # cumulative J of a constant 2 W
        batch = SourceBatch(t, t, {c: (times, np.array([2.0])) for c in SENSORS.values()},
                            dict.fromkeys(SENSORS.values(), energy), dict.fromkeys(SENSORS.values(), "ok"))
        _fresh, closed = self.book.on_batch(batch)
        if self.windows is not None:
            counts = {ch: {role: rate * share * t / 1e9 for role, rate in RATES.items()} for ch, share in SHARE.items()}
            self.windows.observe(CounterSnapshot(t, counts), now_mono_ns=t)
            self.windows.track(self.book.windows, self.book.sample_time_of)
        for window in closed:
            if window.window is None or not window.window.job_id:
                continue
            if self.on_closed is not None:
                self.on_closed(window)
            else:
                self.finished.append(self.jobs.finished(window))

    def steps(self, n: int) -> None:
        for _ in range(n):
            self.step()


def _job_through_a_kill(counters: bool = True) -> JobRecord:
    """A job measured in two segments: 1 s, a daemon killed (2 s unmeasured), 2 s more, stopped."""
    clock = [1_000_000_000]
    first = FakeNode(clock, counters=counters)
    first.steps(3)
    first.jobs.start(parse_job_args({"job_id": "77", "user": "alice", "uid": 1000}))
    first.steps(100)
    (checkpoint,) = first.jobs.checkpoint()
    stored = checkpoint.to_dict()  # what the store holds when the daemon is killed
    clock[0] += 2_000_000_000
    second = FakeNode(clock, counters=counters)
    second.steps(2)
    second.jobs.resume(JobRecord.from_dict(stored))
    second.steps(200)
    assert second.jobs.stop("77") is None
    second.steps(2)
    (record,) = second.finished
    return record


@pytest.fixture(scope="module")
def record() -> JobRecord:
    return _job_through_a_kill()


def test_a_jobs_counted_commands_are_the_sum_of_its_segments(record: JobRecord) -> None:
    """Each segment carries its own window's counts; the job's are their sum, per channel and role."""
    assert record.state == "done" and len(record.segments) == 2 and record.status.startswith("gap:")
    assert all(s.counters is not None and s.counters["status"] == "ok" for s in record.segments)
    total = record.counters
    assert total is not None and total["status"] == "ok" and total["segments_counted"] == 2
    assert total["window_s"] == pytest.approx(sum(s.counters["window_s"] for s in record.segments if s.counters))
    for channel, share in SHARE.items():
        for role in RATES:
            parts = [s.counters["channels"][channel][role] for s in record.segments if s.counters]
            assert total["channels"][channel][role] == pytest.approx(sum(parts), rel=1e-12, abs=1e-9)
        # and the counts are the counters' rates over the counted window (~3 s), not the unmeasured gap
        assert total["channels"][channel]["act"] == pytest.approx(RATES["act"] * share * total["window_s"], rel=1e-9)
    assert 2.9 < total["window_s"] < 3.1


def test_the_model_split_sums_to_the_model_total(record: JobRecord) -> None:
    """The modelled energy by component from the summed counts adds up to the model's totals, by
    component, by kind and by sensor; every component the counts drive is positive."""
    modeller = RunModeller(MEMSPEC, dimms=2)
    model, error = modeller.model_counters(record.counters, record.energy_j)
    assert model is not None, error
    assert model["source"] == "counters" and model["calibrated_j"] is None  # no fit yet: datasheet only
    datasheet = model["components_j"]["datasheet"]
    assert set(datasheet) == set(COMPONENTS)
    assert sum(datasheet.values()) == pytest.approx(model["datasheet_j"], rel=1e-12)
    split = model["split_j"]["datasheet"]
    assert set(split) == set(COMPONENT_KINDS) and sum(split.values()) == pytest.approx(model["datasheet_j"], rel=1e-12)
    for kind in ("background", "activation", "read", "write", "refresh"):
        assert split[kind] > 0, kind
    assert model["counts"]["act"] == pytest.approx(sum(record.counters["channels"][c]["act"] for c in SHARE))
    sensors = model["sensors"]
    assert set(sensors) == set(SENSORS.values())
    assert sum(s["datasheet_j"] for s in sensors.values()) == pytest.approx(model["datasheet_j"], rel=1e-9)
    assert sensors["DDR_AB"]["datasheet_j"] > sensors["DDR_CD"]["datasheet_j"]  # twice the traffic
    assert sensors["DDR_AB"]["measured_j"] == pytest.approx(record.energy_j["DDR_AB"])


def test_calibrated_components_add_up_with_the_intercept(record: JobRecord) -> None:
    """With calibrated currents (here: the datasheet's doubled), the calibrated components plus the
    fit's intercept are the calibrated total."""
    modeller = RunModeller(MEMSPEC, dimms=2)
    fit = {"currents": {"idd0": {"calibrated": 2 * modeller.spec.currents["idd0"]}}, "intercept_j": 1.5}
    modeller.latest_fit = lambda: fit  # type: ignore[method-assign]
    model, error = modeller.model_counters(record.counters, record.energy_j)
    assert model is not None, error
    calibrated = model["components_j"]["calibrated"]
    assert model["calibrated_j"] == pytest.approx(sum(calibrated.values()) + 1.5, rel=1e-12)
    assert calibrated["act_j"] > model["components_j"]["datasheet"]["act_j"]  # IDD0 drives activations


def test_an_open_jobs_energy_so_far_carries_its_counts_so_far() -> None:
    clock = [1_000_000_000]
    node = FakeNode(clock)
    node.steps(2)
    node.jobs.start(parse_job_args({"job_id": "5"}))
    node.steps(50)
    live = node.jobs.snapshot("5")
    assert live is not None and live.counters is not None and live.model is None
    assert live.counters["channels"]["S0.imc0"]["cas_rd"] == pytest.approx(RATES["cas_rd"] * live.counters["window_s"])
    assert live.model_error is not None and live.model_error.startswith("running")


def test_without_counters_a_job_has_no_model_and_says_why() -> None:
    record: Any = _job_through_a_kill(counters=False)
    assert record.counters is None and record.model is None
    assert record.model_error.startswith("no counters")
    body = record.to_dict()
    assert body["model"] is None and not math.isnan(record.dram_energy_j)


class _Publisher:
    def __init__(self) -> None:
        self.published: list[tuple[str, Any]] = []

    def publish(self, kind: str, body: Any, *, t_ns: int | None = None) -> bool:
        self.published.append((kind, body))
        return True


def test_a_stopped_job_is_stored_closed_before_its_model_and_with_it_after(tmp_path: Path) -> None:
    """job.stop with counters: the finished record is stored at once (a daemon that stops before the
    model worker ran keeps the job closed, not running, and the restarted daemon models it), the
    model is computed on the model worker, and the stop is answered with the record that has it,
    stored again."""
    clock = [1_000_000_000]
    node = FakeNode(clock)
    store = Store(tmp_path / "state.db")
    writer = StoreWorker(store)
    queued: list[tuple[Any, Any, Any]] = []  # the model worker, run by hand
    replies: list[Any] = []
    calibration = SimpleNamespace(modeller=RunModeller(MEMSPEC, dimms=2))
    ops = JobOperations(node.jobs, store=writer, publisher=_Publisher(), reply=lambda _p, body, error: replies.append(
        (body, error)), poll=node.step, submit=lambda job, done, failed: queued.append((job, done, failed)),
        calibration=calibration)
    node.on_closed = ops.window_closed

    def drain() -> None:
        while writer.pending:
            for future, _done, _failed in list(writer.jobs.pending):
                future.exception(timeout=30)
            writer.collect()

    try:
        ops.op_job_start({"job_id": "9", "user": "bob"})
        drain()
        assert replies.pop()[0]["state"] == "running"
        node.steps(100)
        ops.op_job_stop({"job_id": "9"})
        node.steps(2)
        drain()
        assert len(queued) == 1 and not replies
        (stored,) = store.list_jobs(job_id="9")
        assert stored["state"] == "done" and stored["model"] is None and stored["model_error"] == MODELLING
        # a daemon restarted here (the queued model job lost) models it again from the store
        again = JobOperations(FakeNode([clock[0]]).jobs, store=writer, publisher=_Publisher(), reply=lambda *_: None,
                              poll=lambda: None, submit=lambda job, done, failed: queued.append((job, done, failed)),
                              calibration=calibration)
        assert again.remodel(unmodelled_jobs(store)) == 1
        job, done, _failed = queued.pop()
        done(job())
        drain()
        (remodelled,) = store.list_jobs(job_id="9")
        assert remodelled["model"]["source"] == "counters" and remodelled["model_error"] is None
        assert unmodelled_jobs(store) == []
        job, done, _failed = queued.pop()  # the first daemon's model job: it answers the stop
        done(job())
        drain()
        ((body, error),) = replies
        assert error is None and body["model"]["source"] == "counters" and body["model_error"] is None
        (stored,) = store.list_jobs(job_id="9")
        assert stored["model"]["datasheet_j"] == pytest.approx(body["model"]["datasheet_j"])
    finally:
        writer.shutdown()
        store.close()


def test_jobs_job_prints_the_split_or_why_there_is_none(record: JobRecord) -> None:
    """``hdeem-watch jobs --job ID``'s model lines: the split by kind (calibrated when fitted), or the reason."""
    from hdeem_watch.cli.jobs import model_lines

    model, _ = RunModeller(MEMSPEC, dimms=2).model_counters(record.counters, record.energy_j)
    with_model = model_lines([{"node": "n1", "ok": True, "jobs": [{**record.to_dict(), "model": model}]}])
    assert len(with_model) == 3 and "datasheet" in with_model[1]
    assert with_model[2].strip() == "currents: datasheet currents of samsung-m393a1g43db0-cpb"
    assert all(kind.replace("_", "-") in with_model[1] for kind in COMPONENT_KINDS)
    bare = _job_through_a_kill(counters=False).to_dict()
    (line,) = model_lines([{"node": "n1", "ok": True, "jobs": [bare]}, {"node": "n2", "ok": False, "error": "x"}])
    assert bare["state"] != "running" and "model: – (no counters" in line
    # a running job is modelled when it stops: no line yet (the job's own output ends with its energy line)
    assert model_lines([{"node": "n1", "ok": True, "jobs": [{**bare, "state": "running"}]}]) == []
