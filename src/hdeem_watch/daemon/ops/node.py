"""The control operations of the daemon, over the run book and narrow ports.

Ops (see ``docs/protocol.md``): ``ping``, ``status``, ``run.start``, ``run.stop``, ``runs.list``,
``baseline.get``, ``baseline.measure``, ``baseline.cancel``, ``calib.get``, ``calib.reset`` (the
``job.*`` ops are :mod:`hdeem_watch.daemon.ops.jobs`'s; closed job windows go there).

``run.start`` polls the source, opens the run in the :class:`~hdeem_watch.daemon.book.state.NodeState`
and tells the source (a :class:`~hdeem_watch.sources.base.RunAware` sim reacts to it); it replies once
the record is stored. ``run.stop`` polls again, tells the source and asks the window to close; its
reply comes when the window closed, the model worker modelled the run and refitted the calibrator,
and the result is stored. A run that was being modelled when the daemon died is modelled again at
the next start (:meth:`Operations.resume_modelling`). Everything that reads or writes the database
runs on the store worker, never on the poll loop.

Example:
    >>> sorted(Operations.OPS)[:3]
    ['baseline.cancel', 'baseline.get', 'baseline.measure']
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable
from typing import Any, Literal

from hdeem_watch import __version__
from hdeem_watch.calibrate.run_model import RunModelResult
from hdeem_watch.daemon.book import baselines as bl
from hdeem_watch.daemon.book.runs import parse_run_args
from hdeem_watch.daemon.book.state import ClosedWindow, Conflict, NodeState
from hdeem_watch.daemon.ops.ports import PublisherPort, Reply, Submit
from hdeem_watch.daemon.ops.reporting import Reporter
from hdeem_watch.daemon.shell.control import Handler, OpError, Pending
from hdeem_watch.daemon.shell.workers import Calibration
from hdeem_watch.daemon.store.port import StorePort
from hdeem_watch.daemon.store.worker import StoreWorker
from hdeem_watch.errors import InputError
from hdeem_watch.run_record import FINISHED_STATES, OPAQUE_KERNEL, RunRecord
from hdeem_watch.sources.base import RunAware, RunEvent, Source
from hdeem_watch.wire import protocol
from hdeem_watch.wire.protocol import EncodedResult, quoted

log = logging.getLogger("hdeem_watch.daemon")

#: Longest sensor group name ``calib.reset`` takes (longer ones are refused before the worker sees them).
MAX_GROUP_CHARS = 64

#: ``runs.list`` page sizes: summaries (default, most), and full records (``"full": true``).
DEFAULT_SUMMARIES = 100
MAX_SUMMARIES = 1000
MAX_FULL_RECORDS = 20
#: Recent runs looked at on start for one whose modelling a crash interrupted.
RESUME_SCAN = 50
#: ``runs.list`` pages kept for repeated requests (all dropped when a run is written).
MAX_CACHED_PAGES = 64
#: Waiters key of the idle measurement.
BASELINE = "baseline"


@dataclasses.dataclass(frozen=True)
class Modelled:
    """A run's model as it comes back from the model worker to the poll loop."""

    #: The run's model, fit and error.
    result: RunModelResult
    #: The ``calib`` topic's body after it.
    calib_body: dict[str, Any]
    #: The calibrator's state to store (serialised on the worker; None: no refit).
    state: str | None
    #: Drift alarms of the sensor groups it raised.
    alarms: list[dict[str, Any]]


class Operations:
    """Control handlers of one node.

    Args:
        book: the node's run book.
        calibration: the calibration (model worker side).
        reporter: status, calib and baseline publishing.
        store: the store worker.
        publisher: the ``run`` topic.
        source: told about runs when it is :class:`~hdeem_watch.sources.base.RunAware`.
        submit: the model worker's ``submit``.
        reply: sends a deferred control reply.
        poll: polls the source once now (a tight window edge).
        dispatch: where a window this op closes itself goes (``baseline.cancel``): the node's
            :class:`~hdeem_watch.daemon.ops.router.WindowRouter` (None: :meth:`window_closed`).
        open_jobs: the open jobs the ``status`` reply lists (None: none).
    """

    OPS = ("ping", "status", "run.start", "run.stop", "runs.list", "baseline.get", "baseline.measure",
           "baseline.cancel", "calib.get", "calib.reset")

    def __init__(self, book: NodeState, *, calibration: Calibration, reporter: Reporter, store: StoreWorker,
                 publisher: PublisherPort, source: Source, submit: Submit, reply: Reply,
                 poll: Callable[[], object], dispatch: Callable[[ClosedWindow], None] | None = None,
                 open_jobs: Callable[[], list[dict[str, Any]]] | None = None) -> None:
        self.book = book
        self.calibration = calibration
        self.reporter = reporter
        self.store = store
        self.publisher = publisher
        self.source = source
        self.submit = submit
        self.reply = reply
        self.poll = poll
        #: Deferred replies by run id (or :data:`BASELINE`), answered when that work is done.
        self.waiters: dict[str, list[Pending]] = {}
        self.dispatch = dispatch or self.window_closed
        #: ``runs.list`` pages already read, valid until a run is written (``_runs_generation``).
        self._pages: dict[tuple[Any, ...], EncodedResult] = {}
        self._runs_generation = 0
        self.open_jobs: Callable[[], list[dict[str, Any]]] = open_jobs or list

    def handlers(self) -> dict[str, Handler]:
        """op name → handler."""
        return {op: getattr(self, "op_" + op.replace(".", "_")) for op in self.OPS}

    # -- simple queries --------------------------------------------------------------------------------

    def op_ping(self, args: dict[str, Any]) -> dict[str, Any]:
        """Liveness."""
        return {"pong": True, "t_ns": self.book.wall()}

    def op_status(self, args: dict[str, Any]) -> dict[str, Any]:
        """The heartbeat body plus node, version and counts."""
        body = self.reporter.status_body()
        body.update({"node": self.book.node, "version": __version__, "runs": self.book.next_seq - 1,
                     "model_error": self.calibration.body.get("model_error"), "jobs": self.open_jobs()})
        return body

    def op_runs_list(self, args: dict[str, Any]) -> Pending | EncodedResult:
        """Stored runs, newest first: summaries, or full records with ``"full": true`` (read off the loop)."""
        full = args.get("full", False)
        if not isinstance(full, bool):
            raise OpError("bad-args", f"args.full = {quoted(full)}: expected true or false")
        most = MAX_FULL_RECORDS if full else MAX_SUMMARIES
        limit = args.get("limit", MAX_FULL_RECORDS if full else DEFAULT_SUMMARIES)
        if isinstance(limit, bool) or not isinstance(limit, int) or not 1 <= limit <= most:
            raise OpError("bad-args", f"args.limit = {quoted(limit)}: expected an integer 1..{most}"
                          + ("" if full else " (full records: 1..20)"))
        kernel = args.get("kernel")
        if kernel is not None and not isinstance(kernel, str):
            raise OpError("bad-args", f"args.kernel = {quoted(kernel)}: expected a string")
        before = args.get("before")
        before_seq = None
        if before is not None:
            if not isinstance(before, str) or not before.startswith("r") or not before[1:].isdigit():
                raise OpError("bad-args", f"args.before = {quoted(before)}: expected a run id (the last one of a page)")
            before_seq = int(before[1:])
        key = (limit, kernel, before_seq, full)
        cached = self._pages.get(key)
        if cached is not None:  # many clients asking for the same page: one read until a run changes
            return cached
        pending = Pending("runs.list")
        generation = self._runs_generation

        def read(store: StorePort) -> EncodedResult:
            runs = list_page(store, limit=limit, kernel=kernel, before_seq=before_seq, full=full)
            more = len(runs) == limit and runs[-1].get("run_id") not in (None, "r1")
            # Encoded once, here: a page of full records is ~200 KB of JSON (milliseconds to encode),
            # and a crowd of clients asks for the same page again and again.
            return EncodedResult.of({"runs": runs, "next_before": runs[-1].get("run_id") if more else None})

        def done(body: EncodedResult) -> None:
            if generation == self._runs_generation:
                if len(self._pages) >= MAX_CACHED_PAGES:
                    self._pages.clear()
                self._pages[key] = body
            self.reply(pending, body, None)

        self.store.read(read, done,
                        lambda error: self.reply(pending, None, ("internal", f"{type(error).__name__}: {error}")))
        return pending

    def _save_run(self, record: RunRecord | dict[str, Any], done: Callable[[bool], None] | None = None,
                  calibration: tuple[int, str, dict[str, Any]] | None = None) -> None:
        """Store a run record (and first the calibration that came with it) on the store worker."""
        body = record.to_dict() if isinstance(record, RunRecord) else record
        self._runs_generation += 1
        self._pages.clear()

        def save(store: StorePort) -> bool:
            # The calibration first: a crash between the two leaves the run "modelling", and the
            # restart's remodelling finds the run already in the calibrator (it is not added twice).
            if calibration is not None:
                t_ns, state, fit = calibration
                store.save_calibration(t_ns, state, fit, str(body["run_id"]))
            return store.save_run(body)

        self.store.write(f"run {body['run_id']}", save, done)

    def op_baseline_get(self, args: dict[str, Any]) -> dict[str, Any]:
        """The current baselines."""
        return bl.baselines_body(self.book.baselines)

    def op_calib_get(self, args: dict[str, Any]) -> EncodedResult:
        """The latest calibration (with the sim's truth when simulated)."""
        return self.reporter.calib_reply()

    def op_calib_reset(self, args: dict[str, Any]) -> Pending:
        """Forget the calibration runs (on the worker, after any refit in progress): of every fit, or
        with ``args.group`` of one sensor group (or ``"node"``, the fit of the groups' sum).

        An unknown group is the caller's mistake: a ``bad-args`` reply, logged at INFO with the
        value cut, not a failed model job."""
        group = args.get("group")
        if group is not None and (not isinstance(group, str) or len(group) > MAX_GROUP_CHARS):
            raise OpError("bad-args", f"args.group = {quoted(group)}: expected a sensor group name (e.g. \"DDR_CD\")")
        pending = Pending("calib.reset")
        calibration = self.calibration

        def job() -> tuple[dict[str, Any], str | None] | InputError:
            modeller = calibration.modeller  # read on the worker, after the job that built it
            if modeller is None:
                raise RuntimeError("the calibrator is not available (it failed to build; see the log)")
            try:
                modeller.reset(group)
            except InputError as error:  # an unknown group: answered, not a worker failure
                return error
            state = None if group is None else protocol.dumps(modeller.state()).decode()
            return modeller.body(), state

        def done(result: tuple[dict[str, Any], str | None] | InputError) -> None:
            if isinstance(result, InputError):
                log.info("calib.reset refused: %s", protocol.quoted(str(result)))
                self.reply(pending, None, ("bad-args", str(result)))
                return
            body, state = result
            t_ns = self.book.wall()
            calibration.body = body
            if group is None:
                self.store.write("calib.reset", lambda s: s.clear_calibrator(t_ns),
                                 lambda _written: self._after_reset(pending))
            else:  # the node calibrator keeps its runs: store the state without the group's
                self.store.write(f"calib.reset {group}", lambda s: s.save_calibrator_state(t_ns, state or "{}"),
                                 lambda _written: self._after_reset(pending))

        def failed(error: BaseException) -> None:
            self.reply(pending, None, ("unavailable", str(error)))

        self.submit(job, done, failed)
        return pending

    def _after_reset(self, pending: Pending) -> None:
        self.reporter.publish_calib()
        self.reply(pending, self.reporter.calib_reply(), None)

    # -- runs ------------------------------------------------------------------------------------------

    def _notify_source(self, kind: Literal["start", "stop"], record: RunRecord, t_mono_ns: int) -> None:
        threads, elements, repeat = record.threads, record.elements, record.repeat
        if not isinstance(self.source, RunAware) or threads is None or elements is None or repeat is None:
            return  # (a record the book started always knows them)
        try:
            self.source.on_run(RunEvent(kind=kind, run_id=record.run_id, kernel=record.kernel, threads=threads,
                                        elements=elements, repeat=repeat, t_mono_ns=t_mono_ns))
        except Exception as error:
            log.warning("source on_run(%s) failed: %s", kind, error)

    def op_run_start(self, args: dict[str, Any]) -> Pending:
        """Open a run window; the reply comes once its record is stored."""
        self._conflict(self.book.ensure_free)  # before the arguments: a busy node says so whatever was asked
        run_args = parse_run_args(args, self.book.limits)
        if not run_args.moves_no_traffic and run_args.kernel != OPAQUE_KERNEL:
            try:
                from hdeem_watch.dram.kernels import canonical_kernel

                run_args = dataclasses.replace(run_args, kernel=canonical_kernel(run_args.kernel))
            except ImportError:
                pass
            except InputError as error:
                raise OpError("bad-args", f"args.kernel: {error} (or 'idle')") from None
        self.poll()
        record = self._conflict(lambda: self.book.start_run(run_args))
        self._notify_source("start", record, self.book.windows[-1].t_start_mono_ns)
        body = record.to_dict()
        self.publisher.publish("run", {"event": "start", "run": body})
        pending = Pending("run.start")
        reply = {"run_id": record.run_id, "t_start_ns": record.t_start_ns, "run": body}
        self._save_run(body, lambda written: self.reply(pending, {**reply, "stored": written}, None))
        return pending

    @staticmethod
    def _conflict(action: Callable[[], Any]) -> Any:
        try:
            return action()
        except Conflict as error:
            raise OpError("conflict", str(error)) from None

    def op_run_stop(self, args: dict[str, Any]) -> Pending:
        """Close a run window; the reply (energies, model, fit) comes when it is modelled and stored."""
        run_id = args.get("run_id")
        if not isinstance(run_id, str | int) or isinstance(run_id, bool):
            raise OpError("bad-args", f"args.run_id = {quoted(run_id)}: expected the run id run.start returned")
        run_id = str(run_id)
        abort = args.get("abort", False)
        if not isinstance(abort, bool):
            raise OpError("bad-args", f"args.abort = {quoted(abort)}: expected true or false")
        pending = Pending("run.stop")
        if run_id in self.waiters:  # closing, modelling, or being modelled again after a restart
            self.waiters[run_id].append(pending)
            return pending
        running = self.book.running()
        if running is None or running.run_id != run_id:
            self.store.read(lambda s: s.get_run(run_id), lambda stored: self._stopped_before(pending, run_id, stored),
                            lambda error: self.reply(pending, None, ("internal", f"{type(error).__name__}: {error}")))
            return pending
        self.waiters[run_id] = [pending]
        self.poll()
        window = self.book.stop_run(run_id, abort=abort)
        assert window is not None
        self._notify_source("stop", running, self.book.monotonic())
        for closed in self.book.close_ready():
            self.dispatch(closed)
        return pending

    def _stopped_before(self, pending: Pending, run_id: str, stored: dict[str, Any] | None) -> None:
        if stored is not None and stored.get("state") in FINISHED_STATES:
            # Stopped before: the same answer again (on disk unless the database cannot be written now).
            self.reply(pending, {**stored, "stored": self.store.health() == "ok"}, None)
        elif stored is not None and stored.get("state") == "modelling":
            self.reply(pending, None, ("unavailable", f"run {run_id} is not modelled yet; ask again later"))
        else:
            self.reply(pending, None, ("not-found", f"no run {quoted(run_id)} in progress"))

    # -- idle baselines --------------------------------------------------------------------------------

    def op_baseline_measure(self, args: dict[str, Any]) -> Pending:
        """Measure an idle window of ``seconds``; the reply comes at its end (or at baseline.cancel)."""
        seconds = args.get("seconds")
        self.poll()
        try:
            self._conflict(lambda: self.book.measure_baseline(seconds))  # type: ignore[arg-type]
        except ValueError as error:
            raise OpError("bad-args", str(error)) from None
        pending = Pending("baseline.measure")
        self.waiters[BASELINE] = [pending]
        return pending

    def op_baseline_cancel(self, args: dict[str, Any]) -> dict[str, Any]:
        """End the idle measurement in progress (its caller gets ``unavailable``)."""
        closed = self.book.cancel_baseline()
        if closed is None:
            return {"cancelled": False}
        self.dispatch(closed)
        return {"cancelled": True, "window_s": closed.window_s}

    # -- closing windows -------------------------------------------------------------------------------

    def window_closed(self, closed: ClosedWindow) -> None:
        """Answer, store and model what a closed run or baseline window measured (the router's owner of
        both kinds)."""
        self.reporter.baselines_kept(closed.kept)
        if closed.run is None:
            waiters = self.waiters.pop(BASELINE, [])
            if closed.cancelled:
                for pending in waiters:
                    self.reply(pending, None, ("unavailable", "the measurement was cancelled (baseline.cancel)"))
                return
            body = bl.baselines_body(closed.baselines)
            body["window_s"] = closed.window_s
            for pending in waiters:
                self.reply(pending, body, None)
            return
        record = closed.run
        self.waiters.setdefault(record.run_id, [])
        body = record.to_dict()
        if record.state == "aborted":
            self._save_run(body, lambda written: self._finished(record, stored=written))
            return
        self._save_run(body)
        self.model(record)

    def model(self, record: RunRecord) -> None:
        """Model the run and refit on the model worker; store the result; then publish and reply."""
        calibration = self.calibration
        self.waiters.setdefault(record.run_id, [])
        snapshot = dataclasses.replace(record)  # the worker's own copy of the record

        def job() -> Modelled:
            modeller = calibration.modeller  # read on the worker, after the job that built it
            if modeller is None:
                raise RuntimeError("the model is not available (it failed to build; see the log)")
            try:
                result = modeller.evaluate(snapshot)
            except Exception as exc:  # a model bug must not lose the run or its reply
                log.exception("modelling run %s failed", record.run_id)
                result = RunModelResult(None, None, f"model failed: {type(exc).__name__}: {exc}")
            # The calibrator's state grows with the runs: serialise it here, not in the poll loop.
            state = protocol.dumps(modeller.state()).decode() if result.fit is not None else None
            alarms = [alarm.to_dict() for alarm in modeller.take_alarms()]
            return Modelled(result, modeller.body(), state, alarms)

        def failed(error: BaseException) -> None:
            self._modelled(record, Modelled(RunModelResult(None, None, str(error)), calibration.body, None, []))

        self.submit(job, lambda modelled: self._modelled(record, modelled), failed)

    def _modelled(self, record: RunRecord, modelled: Modelled) -> None:
        (model, fit, error), state, alarms = modelled.result, modelled.state, modelled.alarms
        calib_body = modelled.calib_body
        done = dataclasses.replace(record, state="done", model=model, fit=fit, model_error=error)
        self.calibration.body = calib_body
        for alarm in alarms:  # drift alarms of the sensor groups: an event on the stream
            log.warning("calibration alarm: %s %s (%s, %s) after run %s", alarm.get("group"), alarm.get("current"),
                        alarm.get("kind"), alarm.get("direction"), record.run_id)
            self.publisher.publish("alarm", {"event": "alarm", "run_id": record.run_id, "alarm": alarm})
            self.store.write(f"alarm {alarm.get('group')}", _save_alarm(int(alarm.get("time_ns") or 0), record.run_id, alarm))
        calibration = (int(done.t_stop_ns or 0), state, fit) if fit is not None and state is not None else None
        self._save_run(done, lambda written: self._finished(done, calib=True, stored=written), calibration)

    def _finished(self, record: RunRecord, *, calib: bool = False, stored: bool = True) -> None:
        """Publish a finished run and answer its stops (``stored``: whether its record is on disk)."""
        body = record.to_dict()
        self.publisher.publish("run", {"event": "stop", "run": body})
        if calib:
            self.reporter.publish_calib()
        for pending in self.waiters.pop(record.run_id, []):
            self.reply(pending, {**body, "stored": stored}, None)

    def resume_modelling(self, stored: list[dict[str, Any]]) -> int:
        """Model again the runs a crash left ``modelling`` (``stored``: their records); return how many."""
        count = 0
        for data in sorted(stored, key=lambda r: int(str(r.get("run_id", "r0"))[1:] or 0)):
            try:
                record = RunRecord.from_dict(data, strict=True)
            except ValueError as error:
                log.warning("stored run %s cannot be modelled again: %s", data.get("run_id"), error)
                continue
            log.info("run %s: modelling again (the daemon stopped while modelling it)", record.run_id)
            self.model(record)
            count += 1
        return count


def _save_alarm(t_ns: int, run_id: str, alarm: dict[str, Any]) -> Callable[[StorePort], None]:
    return lambda store: store.save_alarm(t_ns, run_id, alarm)


def unfinished_runs(store: StorePort) -> list[dict[str, Any]]:
    """The recent stored runs whose modelling a crash interrupted (state ``modelling``), full records."""
    found = [store.get_run(str(r["run_id"])) for r in store.list_runs(RESUME_SCAN) if r.get("state") == "modelling"]
    return [r for r in found if r is not None]


def list_page(store: StorePort, *, limit: int, kernel: str | None, before_seq: int | None,
              full: bool) -> list[dict[str, Any]]:
    """One page of stored runs, newest first (on the store worker): summaries unless ``full``;
    with ``before_seq`` the runs numbered below it (the ids are sequential, ``r<n>``)."""
    return store.list_runs(limit, kernel, full=full, before=before_seq)
