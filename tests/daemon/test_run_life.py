"""A run's whole life without sockets: start → windows → energy → model → refit → reply.

The run book (:class:`NodeState`) and the control operations are driven with a fake monotonic and
wall clock and a small fake DRAM node that reacts to runs (it is ``RunAware``, like the sim); the
database is a real SQLite file on the real store worker thread, the model and the refit the real
ones on the real model worker. Only the publisher is a recorder (the real one is tested over
sockets elsewhere).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hdeem_watch.daemon.book import baselines as bl
from hdeem_watch.daemon.book.runs import RunLimits
from hdeem_watch.daemon.book.state import MAX_BASELINE_S, NodeState
from hdeem_watch.daemon.compose import NodePorts, build_node
from hdeem_watch.daemon.ops.node import unfinished_runs
from hdeem_watch.daemon.ops.reporting import Identity
from hdeem_watch.daemon.shell.control import OpError, Pending, dispatch
from hdeem_watch.daemon.shell.workers import ModelSettings, Worker, restore_calibration
from hdeem_watch.daemon.store.database import Store
from hdeem_watch.daemon.store.worker import StoreWorker
from hdeem_watch.run_record import RunRecord
from hdeem_watch.sources.base import ChannelInfo, RunAware, RunEvent, SourceBatch
from hdeem_watch.wire.protocol import EncodedResult, ProtocolError, decode_reply

MEMSPEC = "samsung-m393a1g43db0-cpb"
DRAM = ("DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH")
IDLE_W, BUSY_W = 2.0, 6.0
PERIOD_NS = 10_000_000  # 100 Sa/s
POLL_NS = 40_000_000
WALL0 = 1_700_000_000 * 10**9


class FakeDramNode:
    """Four DRAM channels at 100 Sa/s: 2 W idle, 6 W while a run with traffic is on; sample time =
    monotonic time. ``gap`` withholds samples (a sensor gap: nothing measured, energy unchanged)."""

    kind = "fake"

    def __init__(self, clock: Any) -> None:
        self.clock = clock
        self.k = 0
        self.energy = dict.fromkeys(DRAM, 0.0)
        self.busy_from: int | None = None
        self.busy_until: int | None = None
        self.gap = False
        self.fail = False
        self.unknown = False
        self.events: list[RunEvent] = []

    def channels(self) -> list[ChannelInfo]:
        return [ChannelInfo(name, 100.0, "dram") for name in DRAM]

    def open(self) -> None: ...

    def close(self) -> None: ...

    def health(self) -> str:
        return "ok"

    def on_run(self, event: RunEvent) -> None:
        self.events.append(event)
        if event.kind == "start" and event.kernel != "idle":
            self.busy_from, self.busy_until = event.t_mono_ns, None
        elif event.kind == "stop":
            self.busy_until = event.t_mono_ns

    def power(self, t_ns: int) -> float:
        on = self.busy_from is not None and t_ns > self.busy_from and (self.busy_until is None or t_ns <= self.busy_until)
        return BUSY_W if on else IDLE_W

    def poll(self) -> SourceBatch:
        if self.fail:
            raise OSError("sensor bus timeout")
        now = self.clock()
        last = now // PERIOD_NS
        if self.gap:
            self.k = last
            t, p = np.empty(0, dtype=np.int64), np.empty(0)
        else:
            t = np.arange(self.k + 1, last + 1, dtype=np.int64) * PERIOD_NS
            p = np.array([math.nan if self.unknown else self.power(int(x)) for x in t])
            self.k = last
        samples = {}
        for name in DRAM:
            self.energy[name] += float(p.sum()) * PERIOD_NS / 1e9
            samples[name] = (t, p)
        energy = dict.fromkeys(DRAM, math.nan) if self.unknown else dict(self.energy)
        return SourceBatch(now, now, samples, energy, dict.fromkeys(DRAM, "stale" if self.unknown else "ok"))


class Recorder:
    """The publisher port: keeps what was published."""

    def __init__(self) -> None:
        self.messages: list[tuple[str, dict[str, Any]]] = []

    def publish(self, kind: str, body: Any, /) -> bool:
        self.messages.append((kind, dict(body)))
        return True

    def kinds(self, kind: str) -> list[dict[str, Any]]:
        return [body for k, body in self.messages if k == kind]


class Node:
    """The daemon's core and operations over their ports, on a fake clock (no sockets)."""

    def __init__(self, state_dir: Path, *, memspec: str = MEMSPEC, run_models: bool = True) -> None:
        self.now = 1_000 * PERIOD_NS
        self.source = FakeDramNode(lambda: self.now)
        self.store = Store(state_dir / "state.db")
        self.store.close_interrupted_runs(self.wall())
        self.book = NodeState(self.source.channels(), node="n1", monotonic=lambda: self.now, wall=self.wall,
                              next_seq=int(self.store.next_run_id()[1:]), limits=RunLimits(256, 1 << 34),
                              baselines={c: bl.Baseline.from_dict(d) for c, d in self.store.load_baselines().items()})
        self.source.k = self.now // PERIOD_NS
        self.writer = StoreWorker(self.store)
        self.models = Worker("model")
        self.publisher = Recorder()
        self.replies: dict[int, tuple[Any, tuple[str, str] | None]] = {}
        submit = self.models.submit if run_models else (lambda job, done, failed=None: None)
        ports = NodePorts(store=self.writer, submit=submit, publisher=self.publisher, reply=self.reply, poll=self.poll)
        self.core = build_node(self.book, self.source, lambda: self.now, ports, identity=Identity(kind="fake", endpoints={}),
                               poll_interval_ns=lambda: POLL_NS)
        self.calibration, self.reporter, self.ops = self.core.calibration, self.core.reporter, self.core.operations
        restore_calibration(self.calibration, settings=ModelSettings(memspec, max_requests=100_000),
                            state=self.store.load_calibrator(), fits=self.store.fit_history(200),
                            submit=self.models.submit, on_built=self.reporter.publish_calib)
        assert isinstance(self.source, RunAware)

    def wall(self) -> int:
        return WALL0 + self.now

    def reply(self, pending: Pending, result: Any, error: tuple[str, str] | None) -> None:
        self.replies[id(pending)] = (result, error)

    def poll(self) -> None:
        """What the daemon's poll step does with the source (without publishing samples)."""
        try:
            batch = self.source.poll()
        except OSError as error:
            self.book.on_poll_error(error)
            closed = self.book.close_ready()
        else:
            _fresh, closed = self.book.on_batch(batch)
        for window in closed:
            self.core.window_closed(window)

    def advance(self, seconds: float) -> None:
        for _ in range(round(seconds * 1e9 / POLL_NS)):
            self.now += POLL_NS
            self.poll()

    def settle(self) -> None:
        """Wait for both workers and run their callbacks (as the loop would)."""
        while self.models.pending or self.writer.pending:
            for worker in (self.models, self.writer.jobs):
                for future, _done, _failed in list(worker.pending):
                    future.exception(timeout=60)
                worker.collect()

    def call(self, op: str, args: dict[str, Any] | None = None) -> Any:
        """Call an op; a deferred reply is waited for (advancing the clock while a window closes)."""
        try:
            result = self.ops.handlers()[op](args or {})
        except (OpError, ProtocolError) as error:
            raise OpFailed(error.code, str(error)) from None
        if not isinstance(result, Pending):
            return decoded(result)
        for _ in range(500):
            self.settle()
            if id(result) in self.replies:
                value, error = self.replies.pop(id(result))
                if error is not None:
                    raise OpFailed(*error)
                return decoded(value)
            self.advance(POLL_NS / 1e9)
        raise AssertionError(f"{op}: no reply")

    def close(self) -> None:
        self.models.shutdown(cancel_queued=True)
        self.writer.shutdown()
        self.store.close()


def decoded(result: Any) -> Any:
    """A result as a client reads it (the control server sends a pre-encoded one as it is)."""
    return result.decoded() if isinstance(result, EncodedResult) else result


class OpFailed(Exception):
    def __init__(self, code: str, message: str) -> None:
        super().__init__(f"{code}: {message}")
        self.code = code


@pytest.fixture
def node(tmp_path: Path) -> Any:
    made = Node(tmp_path)
    yield made
    made.close()


def test_a_run_from_start_to_reply(node: Node) -> None:
    """An idle run and a triad run: exact window energies, idle baselines, the model, a refit per run,
    the prediction from the fit before, the run events, the stored records and the replies."""
    node.advance(0.5)
    idle = node.call("run.start", {"kernel": "idle"})
    assert idle["run"]["state"] == "running" and node.store.get_run(idle["run_id"])["state"] == "running"
    node.advance(1.0)
    first = node.call("run.stop", {"run_id": idle["run_id"]})
    triad = node.call("run.start", {"kernel": "triad", "threads": 24, "elements": 1 << 22, "repeat": 4})
    node.advance(0.5)
    second = node.call("run.stop", {"run_id": triad["run_id"]})

    assert first["state"] == second["state"] == "done"
    assert first["window_s"] == pytest.approx(1.0, abs=0.011)
    assert first["dram_energy_j"] == pytest.approx(4 * IDLE_W * first["window_s"], rel=1e-9)
    assert second["dram_energy_j"] == pytest.approx(4 * BUSY_W * second["window_s"], rel=1e-9)
    assert first["model"]["counts"] and first["fit"]["n_runs"] == 1 and first["model"]["calibrated_j"] is None
    assert second["fit"]["n_runs"] == 2 and second["model"]["predicted_j"] > 0
    # The idle run is every channel's idle baseline (stored too).
    for name in DRAM:
        assert node.book.baselines[name].origin == "idle-run"
        assert node.book.baselines[name].power_w == pytest.approx(IDLE_W)
    node.settle()
    assert node.store.load_baselines().keys() == set(DRAM)
    assert [e.kind for e in node.source.events] == ["start", "stop", "start", "stop"]
    runs = [(body["event"], body["run"]["run_id"]) for body in node.publisher.kinds("run")]
    assert runs == [("start", "r1"), ("stop", "r1"), ("start", "r2"), ("stop", "r2")]
    assert node.publisher.kinds("calib")[-1]["fit"]["n_runs"] == 2
    assert node.store.get_run("r2")["fit"]["n_runs"] == 2 and node.store.fit_history()[-1][1] == "r2"
    # A retried stop gets the same answer; runs.list sends summaries, full records on request.
    assert node.call("run.stop", {"run_id": "r2"})["fit"] == second["fit"]
    listed = node.call("runs.list")
    assert [r["run_id"] for r in listed["runs"]] == ["r2", "r1"] and listed["next_before"] is None
    assert "observation" not in listed["runs"][0]["model"] and listed["runs"][0]["fit"]["n_runs"] == 2
    page = node.call("runs.list", {"full": True, "limit": 1})
    assert page["runs"][0]["model"]["observation"] and page["next_before"] == "r2"
    assert [r["run_id"] for r in node.call("runs.list", {"full": True, "before": "r2"})["runs"]] == ["r1"]
    # The same page again is answered at once from the last read, until a run is written.
    again = node.ops.handlers()["runs.list"]({})
    assert isinstance(again, EncodedResult) and again.decoded() == listed
    node.call("run.start", {"kernel": "idle"})
    assert [r["run_id"] for r in node.call("runs.list")["runs"]] == ["r3", "r2", "r1"]


def test_conflicts_abort_and_bad_arguments(node: Node) -> None:
    """A second run.start is a conflict; an aborted run is stored but not modelled; a stop of an unknown run is not-found."""
    run = node.call("run.start", {"kernel": "read", "elements": 1 << 20})
    for op, args in (("run.start", {"kernel": "read"}), ("baseline.measure", {"seconds": 1})):
        with pytest.raises(OpFailed) as info:
            node.call(op, args)
        assert info.value.code == "conflict"
    node.advance(0.2)
    stopped = node.call("run.stop", {"run_id": run["run_id"], "abort": True})
    assert stopped["state"] == "aborted" and stopped["fit"] is None and stopped["model"] is None
    assert node.call("run.stop", {"run_id": run["run_id"]})["state"] == "aborted"
    with pytest.raises(OpFailed) as info:
        node.call("run.stop", {"run_id": "r99"})
    assert info.value.code == "not-found"


@pytest.mark.parametrize("body", [
    b'{"op": "run.start", "args": {"kernel": "triad", "elements": 1e300}}',
    b'{"op": "run.start", "args": {"kernel": "triad", "elements": 1000000000000000000}}',
    b'{"op": "run.start", "args": {"kernel": "triad", "threads": 24.0}}',
    b'{"op": "run.start", "args": {"kernel": "triad", "threads": 100000}}',
    b'{"op": "run.start", "args": {"kernel": "triad", "repeat": 1e18}}',
    b'{"op": "run.start", "args": {"kernel": "triad", "repeat": NaN}}',
    b'{"op": "run.start", "args": {"kernel": "triad", "elements": Infinity}}',
    b'{"op": "run.start", "args": {"kernel": "triad", "name": "\\ud800"}}',
    b'{"op": "baseline.measure", "args": {"seconds": NaN}}',
    b'{"op": "baseline.measure", "args": {"seconds": 3600}}',
])
def test_absurd_numbers_are_bad_args(node: Node, body: bytes) -> None:
    """Integers only where integers are meant, within the node's bounds; NaN/Infinity are bad-args, never internal."""
    reply = dispatch(body, node.ops.handlers())
    assert isinstance(reply, bytes)
    assert decode_reply(reply).code in ("bad-args", "bad-json"), reply
    assert not node.book.windows


def test_implausible_energy_never_enters_the_fit(node: Node) -> None:
    """A measured energy that is not finite or far beyond what DIMMs draw is reported, not calibrated."""
    node.settle()
    modeller = node.calibration.modeller
    assert modeller is not None
    base = {"kernel": "triad", "threads": 24, "elements": 1 << 22, "repeat": 4, "window_s": 1.0, "t_stop_ns": 1}
    for i, energy in enumerate((4e290, math.inf, math.nan, 1e6)):
        _model, fit, error = modeller.evaluate(RunRecord.from_dict({**base, "run_id": f"r{i}", "state": "modelling",
                                                                    "dram_energy_j": energy}))
        assert fit is None and error, energy
    assert modeller.calibrator.observations == []


def test_a_sensor_gap_yields_no_baseline(node: Node) -> None:
    """An idle window without samples stores no 0 W baseline and keeps the real one."""
    node.advance(0.2)
    node.call("baseline.measure", {"seconds": 1.0})
    real = dict(node.book.baselines)
    assert real.keys() == set(DRAM) and all(b.n > 0 for b in real.values())
    node.source.gap = True
    body = node.call("baseline.measure", {"seconds": 1.0})
    assert body["channels"] == {}
    run = node.call("run.start", {"kernel": "idle"})
    node.advance(0.5)
    node.call("run.stop", {"run_id": run["run_id"]})
    node.settle()
    assert node.book.baselines == real
    assert {c: bl.Baseline.from_dict(d) for c, d in node.store.load_baselines().items()} == real


def test_baseline_measure_is_bounded_and_can_be_cancelled(node: Node) -> None:
    """A long idle measurement blocks run.start until baseline.cancel ends it; its caller is told."""
    measure = node.ops.handlers()["baseline.measure"]({"seconds": MAX_BASELINE_S})
    node.advance(0.2)
    with pytest.raises(OpFailed):
        node.call("run.start", {"kernel": "idle"})
    cancelled = node.call("baseline.cancel")
    assert cancelled["cancelled"] is True and cancelled["window_s"] == pytest.approx(0.2, abs=0.05)
    assert node.replies.pop(id(measure))[1][0] == "unavailable"
    assert node.call("baseline.cancel") == {"cancelled": False}
    assert node.call("run.start", {"kernel": "idle"})["run_id"] == "r1"


def test_a_crash_during_the_refit_is_modelled_again_at_restart(tmp_path: Path) -> None:
    """A run whose model had not finished is stored 'modelling' (never 'done' without a model); the
    restarted daemon models it, and the retried run.stop gets the modelled record."""
    crashed = Node(tmp_path, run_models=False)  # the model worker never answers: the daemon dies during the refit
    run = crashed.ops.handlers()["run.start"]({"kernel": "idle"})
    crashed.settle()
    crashed.advance(0.5)
    stop = crashed.ops.handlers()["run.stop"]({"run_id": "r1"})
    crashed.advance(0.2)
    crashed.settle()
    assert isinstance(run, Pending) and isinstance(stop, Pending) and id(stop) not in crashed.replies
    assert crashed.store.get_run("r1")["state"] == "modelling"
    crashed.close()

    restarted = Node(tmp_path)
    try:
        assert restarted.ops.resume_modelling(unfinished_runs(restarted.store)) == 1
        record = restarted.call("run.stop", {"run_id": "r1"})
        assert record["state"] == "done" and record["model"] is not None and record["fit"]["n_runs"] == 1
        assert restarted.store.get_run("r1")["fit"]["n_runs"] == 1
        # Modelled again but already in the calibrator (the crash came after its save): not added twice.
        restarted.store.save_run({**record, "state": "modelling"})
        restarted.ops.resume_modelling(unfinished_runs(restarted.store))
        restarted.settle()
        again = restarted.store.get_run("r1")
        assert again["state"] == "done" and "already" in again["model_error"]
        assert restarted.calibration.modeller is not None
        assert len(restarted.calibration.modeller.calibrator.observations) == 1
    finally:
        restarted.close()


def test_source_failures_and_unknown_values_are_reported_not_fatal(node: Node) -> None:
    """A failing poll shows as an error status and health until a heartbeat after it recovered;
    unknown energy stays unknown and is not modelled."""
    node.advance(0.2)
    node.source.fail = True
    node.advance(0.2)
    failing = node.reporter.status_body()
    node.reporter.publish_status()  # a heartbeat while it fails keeps the error
    node.source.fail = False
    node.advance(0.2)
    still = node.reporter.status_body()
    node.reporter.publish_status()
    recovered = node.publisher.kinds("status")[-1]
    assert failing["source"]["health"] == "error: OSError: sensor bus timeout"
    assert failing["channels"]["DDR_AB"]["status"].startswith("error")
    assert still["source"]["health"].startswith("error") and still["channels"]["DDR_AB"]["status"] == "ok"
    assert recovered["source"]["health"] == "ok" and recovered["store"]["health"] == "ok"
    node.source.unknown = True
    run = node.call("run.start", {"kernel": "idle"})
    node.advance(0.2)
    record = node.call("run.stop", {"run_id": run["run_id"]})
    assert math.isnan(record["energy_j"]["DDR_AB"]) and math.isnan(record["dram_energy_j"])
    assert record["model"] is None and "no measured DRAM energy" in record["model_error"]


@pytest.mark.parametrize("failure", ["bad-preset", "crash"])
def test_a_failing_model_still_answers_run_stop(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, failure: str) -> None:
    """If the model cannot be built (bad memspec, or a crash), run.stop still replies with the energies and why."""
    from hdeem_watch.daemon.shell import workers as jobs

    if failure == "crash":
        def broken(*args: object, **kwargs: object) -> None:
            raise RuntimeError("no-such-preset: simulated crash")

        monkeypatch.setattr(jobs, "RunModeller", broken)  # the model worker's first job builds it
    node = Node(tmp_path, memspec="no-such-preset")
    try:
        run = node.call("run.start", {"kernel": "triad", "elements": 1 << 20})
        node.advance(0.2)
        record = node.call("run.stop", {"run_id": run["run_id"]})
        calib = node.call("calib.get")
    finally:
        node.close()
    assert record["state"] == "done" and record["dram_energy_j"] > 0
    expected = "failed to build" if failure == "crash" else "no-such-preset"
    assert record["model"] is None and expected in record["model_error"]
    assert calib["fit"] is None and "no-such-preset" in calib["model_error"]
