"""The ``job.*`` control ops: SLURM jobs' windows opened, closed, stored and listed.

``job.start`` (the Prolog) polls the source, opens the job's window in the
:class:`~hdeem_watch.daemon.jobs.book.JobBook` and replies once the record is stored; ``job.stop``
(the Epilog) polls again and asks the window to close; its reply comes when the window closed (the
stop cut to the sample, as for a run) and the finished record is stored. ``job.get`` and
``job.list`` read the store on the store worker and show open jobs with their energy so far. Every
:data:`CHECKPOINT_S` the open jobs' energy so far is stored, so a ``kill -9`` loses at most that
much; the restarted daemon resumes them (:meth:`JobOperations.resume`). Each start and stop is
published on the ``job`` topic. With counters, a finished job's energy by component is modelled
from its counted commands on the model worker before it is stored and the stop answered.

Example:
    >>> JobOperations.OPS
    ('job.start', 'job.stop', 'job.get', 'job.list')
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Mapping
from typing import Any, Protocol, cast

from hdeem_watch.daemon.book.state import ClosedWindow, Conflict
from hdeem_watch.daemon.jobs.book import JobBook
from hdeem_watch.daemon.jobs.records import exit_code_arg, job_summary, parse_job_args
from hdeem_watch.daemon.ops.ports import PublisherPort, Reply
from hdeem_watch.daemon.shell.control import Handler, OpError, Pending
from hdeem_watch.daemon.store.port import StorePort
from hdeem_watch.daemon.store.worker import StoreWorker
from hdeem_watch.job_record import JOB_STATES, JobRecord
from hdeem_watch.wire.protocol import quoted
from hdeem_watch.wire.requests import job_id_arg

log = logging.getLogger("hdeem_watch.daemon")

#: Seconds between two stores of the open jobs' energy so far (what a ``kill -9`` may lose).
CHECKPOINT_S = 5.0
#: ``job.list`` page sizes.
DEFAULT_JOBS, MAX_JOBS = 100, 1000
#: Jobs looked at on start for those a previous daemon left running.
RESUME_SCAN = 1000
#: Newest finished jobs (per state) looked at on start for one whose model a stop interrupted.
REMODEL_SCAN = 100
#: ``model_error`` of a finished job while its counters are modelled (it stays if the daemon stops first).
MODELLING = "modelling: the energy by component is computed from the counters (the daemon stopped before if this stays)"


class JobStore(Protocol):
    """What the job ops use of :class:`~hdeem_watch.daemon.store.database.Store`."""

    def save_job(self, record: Mapping[str, Any]) -> bool: ...

    def list_jobs(self, *, job_id: str | None = None, user: str | None = None, since_ns: int | None = None,
                  state: str | None = None, limit: int = 100) -> list[dict[str, Any]]: ...


def _jobs(store: StorePort) -> JobStore:
    return cast(JobStore, store)


class JobOperations:
    """Control handlers of a node's jobs.

    Args:
        jobs: the node's job book.
        store: the store worker.
        publisher: the ``job`` topic.
        reply: sends a deferred control reply.
        poll: polls the source once now (a tight window edge).
        checkpoint_s: seconds between two stores of the open jobs.
        submit: the model worker's ``submit`` (None: finished jobs are not modelled).
        calibration: holds the run modeller (``.modeller``, set on the model worker), which models a
            finished job's counters by component
            (:meth:`~hdeem_watch.calibrate.run_model.RunModeller.model_counters`).
    """

    OPS = ("job.start", "job.stop", "job.get", "job.list")

    def __init__(self, jobs: JobBook, *, store: StoreWorker, publisher: PublisherPort, reply: Reply,
                 poll: Callable[[], object], checkpoint_s: float = CHECKPOINT_S,
                 submit: Callable[..., None] | None = None, calibration: Any = None,
                 dispatch: Callable[[ClosedWindow], None] | None = None) -> None:
        self.jobs = jobs
        self.submit = submit
        self.calibration = calibration
        self.store = store
        self.publisher = publisher
        self.reply = reply
        self.poll = poll
        #: Where the windows a ``job.stop`` closes go: the daemon's dispatcher by window kind
        #: (:meth:`Operations.window_closed`: a run or baseline window may close at the same time).
        self.dispatch = dispatch or self.window_closed
        self.checkpoint_ns = round(checkpoint_s * 1e9)
        self._last_checkpoint_ns = jobs.book.monotonic()
        #: Deferred ``job.stop`` replies by job id.
        self.waiters: dict[str, list[Pending]] = {}

    def handlers(self) -> dict[str, Handler]:
        """op name → handler."""
        return {op: getattr(self, "op_" + op.replace(".", "_")) for op in self.OPS}

    def running_job_uids(self) -> frozenset[int]:
        """The uids owning the jobs open on this node (see :meth:`JobBook.running_job_uids`)."""
        return self.jobs.running_job_uids()

    # -- ops --------------------------------------------------------------------------------------

    def op_job_start(self, args: dict[str, Any]) -> Pending | dict[str, Any]:
        """Open a job's window; the reply (the record) comes once it is stored. A job already open
        (a retried Prolog) gets its record at once."""
        job_args = parse_job_args(args)
        self.poll()
        try:
            record, new = self.jobs.start(job_args)
        except Conflict as error:
            raise OpError("conflict", str(error)) from None
        body = record.to_dict()
        if not new:  # stored with the first start, unless the database cannot be written now
            return {**body, "stored": self.store.health() == "ok"}
        pending = Pending("job.start")
        log.info("job %s started (user %s, uid %s)", record.job_id, record.user, record.uid)
        self.publisher.publish("job", {"event": "start", "job": job_summary(body)})
        self._save(body, lambda written: self.reply(pending, {**body, "stored": written}, None))
        return pending

    def op_job_stop(self, args: dict[str, Any]) -> Pending:
        """Close a job's window; the reply (the finished record) comes when it is stored."""
        job_id = job_id_arg(args.get("job_id"))
        exit_code = exit_code_arg(args.get("exit_code"))
        ended_ns = args.get("ended_ns")
        if ended_ns is not None and (isinstance(ended_ns, bool) or not isinstance(ended_ns, int) or ended_ns < 0):
            raise OpError("bad-args", f"args.ended_ns = {quoted(ended_ns)}: expected the wall-clock ns the job ended")
        pending = Pending("job.stop")
        if job_id in self.waiters:  # closing already: the same answer
            self.waiters[job_id].append(pending)
            return pending
        if self.jobs.is_open(job_id):
            self.poll()
        if not self.jobs.is_open(job_id):  # stopped before, or the poll closed it (a stop already in flight)
            self.store.read(lambda s: _jobs(s).list_jobs(job_id=job_id, limit=1),
                            lambda found: self._stopped_before(pending, job_id, found), self._failed(pending))
            return pending
        self.waiters[job_id] = [pending]
        interrupted = self.jobs.stop(job_id, exit_code, ended_ns=ended_ns)
        if interrupted is not None:
            self._finish(interrupted)
        else:
            for closed in self.jobs.book.close_ready():
                self.dispatch(closed)
        return pending

    def op_job_get(self, args: dict[str, Any]) -> Pending | dict[str, Any]:
        """One job's record (the newest of that id): an open one with its energy so far."""
        job_id = job_id_arg(args.get("job_id"))
        live = self.jobs.snapshot(job_id)
        if live is not None:
            return live.to_dict()
        pending = Pending("job.get")

        def done(found: list[dict[str, Any]]) -> None:
            if found:
                self.reply(pending, found[0], None)
            else:
                self.reply(pending, None, ("not-found", f"no job {quoted(job_id)} on this node"))

        self.store.read(lambda s: _jobs(s).list_jobs(job_id=job_id, limit=1), done, self._failed(pending))
        return pending

    def op_job_list(self, args: dict[str, Any]) -> Pending:
        """Job summaries, newest first; filters ``job_id``, ``user``, ``since_ns``, ``state``, ``limit``;
        ``"full": true`` keeps each record's segments."""
        job_id = None if args.get("job_id") is None else job_id_arg(args.get("job_id"))
        user, state, since_ns = args.get("user"), args.get("state"), args.get("since_ns")
        if user is not None and not isinstance(user, str):
            raise OpError("bad-args", f"args.user = {quoted(user)}: expected a user name")
        if state is not None and state not in JOB_STATES:
            raise OpError("bad-args", f"args.state = {quoted(state)}: expected running, done or interrupted")
        if since_ns is not None and (isinstance(since_ns, bool) or not isinstance(since_ns, int)):
            raise OpError("bad-args", f"args.since_ns = {quoted(since_ns)}: expected wall-clock ns")
        limit = args.get("limit", DEFAULT_JOBS)
        if isinstance(limit, bool) or not isinstance(limit, int) or not 1 <= limit <= MAX_JOBS:
            raise OpError("bad-args", f"args.limit = {quoted(limit)}: expected an integer 1..{MAX_JOBS}")
        full = args.get("full", False)
        if not isinstance(full, bool):
            raise OpError("bad-args", f"args.full = {quoted(full)}: expected true or false")
        pending = Pending("job.list")

        def done(found: list[dict[str, Any]]) -> None:
            jobs = []
            for record in found:  # open jobs as they are now, not as last checkpointed
                live = self.jobs.snapshot(str(record.get("job_id"))) if record.get("state") == "running" else None
                if live is not None and live.t_start_ns == record.get("t_start_ns"):
                    record = live.to_dict()
                jobs.append(record if full else job_summary(record))
            self.reply(pending, {"node": self.jobs.book.node, "jobs": jobs}, None)

        self.store.read(lambda s: _jobs(s).list_jobs(job_id=job_id, user=user, since_ns=since_ns, state=state,
                                                     limit=limit), done, self._failed(pending))
        return pending

    # -- the loop's side --------------------------------------------------------------------------

    def window_closed(self, closed: ClosedWindow) -> None:
        """A job's window closed (after a batch): store the record, publish it, answer the stop."""
        self._finish(self.jobs.finished(closed))

    def checkpoint(self, *, force: bool = False) -> int:
        """Store the open jobs' energy so far when :data:`CHECKPOINT_S` passed (or ``force``, at a
        clean exit); return how many were stored."""
        now = self.jobs.book.monotonic()
        # Called at each heartbeat: a tenth of slack, so that heartbeat jitter does not skip one.
        if not force and now - self._last_checkpoint_ns < 0.9 * self.checkpoint_ns:
            return 0
        self._last_checkpoint_ns = now
        records = self.jobs.checkpoint()
        for record in records:
            self._save(record.to_dict())
        return len(records)

    def resume(self, stored: list[dict[str, Any]]) -> int:
        """Reopen the jobs a previous daemon left running (``stored``: their records); return how many."""
        count = 0
        for data in sorted(stored, key=lambda r: int(r.get("t_start_ns") or 0)):
            try:
                record = JobRecord.from_dict(data, strict=True)
            except ValueError as error:
                log.warning("stored job %s cannot be resumed: %s", data.get("job_id"), error)
                continue
            if self.jobs.is_open(record.job_id):
                continue
            self.jobs.resume(record)
            log.info("job %s: resumed (the daemon stopped while it ran; the time between is marked unmeasured)",
                     record.job_id)
            count += 1
        return count

    # -- helpers ----------------------------------------------------------------------------------

    def _finish(self, record: JobRecord) -> None:
        """A finished job: model its counters on the model worker (when it has any), then store,
        publish and answer the stop."""
        if record.counters is None or self.submit is None or self.calibration is None:
            self._finished(record)
            return
        # Stored finished at once: a daemon that stops before the model is done keeps the job closed.
        self._save(dataclasses.replace(record, model_error=MODELLING).to_dict())
        self._model(record, self._finished)

    def remodel(self, stored: list[dict[str, Any]]) -> int:
        """Model the finished jobs a previous daemon stopped before modelling (``stored``: their
        records, :func:`unmodelled_jobs`); store them with their model; return how many."""
        count = 0
        for data in stored:
            try:
                record = JobRecord.from_dict(data, strict=True)
            except ValueError as error:
                log.warning("stored job %s cannot be modelled: %s", data.get("job_id"), error)
                continue
            if record.counters is None or self.submit is None or self.calibration is None:
                continue
            self._model(record, lambda done: self._save(done.to_dict()))
            count += 1
        return count

    def _model(self, record: JobRecord, then: Callable[[JobRecord], None]) -> None:
        """Model ``record``'s counters on the model worker; ``then(record with model)`` in the loop."""
        assert self.submit is not None
        calibration, counters, measured = self.calibration, record.counters, dict(record.energy_j)

        def job() -> tuple[dict[str, Any] | None, str]:
            modeller = calibration.modeller  # read on the worker, after the job that built it
            if modeller is None:
                return None, "the model is not available (it failed to build; see the log)"
            try:
                model, error = modeller.model_counters(counters, measured)
            except Exception as exc:  # a model bug must not lose the job or its reply
                log.exception("modelling job %s failed", record.job_id)
                return None, f"model failed: {type(exc).__name__}: {exc}"
            return cast("dict[str, Any] | None", model), str(error)

        def done(result: tuple[dict[str, Any] | None, str]) -> None:
            model, error = result
            then(dataclasses.replace(record, model=model, model_error=None if model is not None else error))

        self.submit(job, done, lambda error: done((None, f"model failed: {type(error).__name__}: {error}")))

    def _finished(self, record: JobRecord) -> None:
        body = record.to_dict()
        log.info("job %s %s: DRAM %.1f J over %.1f s (%s)", record.job_id, record.state, record.dram_energy_j,
                 record.measured_s, record.status)
        self.publisher.publish("job", {"event": "stop", "job": job_summary(body)})
        waiters = self.waiters.pop(record.job_id, [])

        def answer(written: bool) -> None:
            for pending in waiters:
                self.reply(pending, {**body, "stored": written}, None)

        self._save(body, answer)

    def _save(self, body: dict[str, Any], done: Callable[[bool], None] | None = None) -> None:
        """Store a job record; ``done(written)``: whether it is on disk (False: kept in memory, retried)."""
        self.store.write(f"job {body['job_id']}", lambda s: _jobs(s).save_job(body), done)

    def _stopped_before(self, pending: Pending, job_id: str, found: list[dict[str, Any]]) -> None:
        if found and found[0].get("state") != "running":
            # Stopped before: the same answer again (on disk unless the database cannot be written now).
            self.reply(pending, {**found[0], "stored": self.store.health() == "ok"}, None)
        else:
            self.reply(pending, None, ("not-found", f"no job {quoted(job_id)} open on this node"))

    def _failed(self, pending: Pending) -> Callable[[BaseException], None]:
        return lambda error: self.reply(pending, None, ("internal", f"{type(error).__name__}: {error}"))


def unmodelled_jobs(store: StorePort) -> list[dict[str, Any]]:
    """The newest finished jobs a previous daemon stopped before their model was done (on the store)."""
    found = []
    for state in ("done", "interrupted"):
        found += [r for r in _jobs(store).list_jobs(state=state, limit=REMODEL_SCAN)
                  if r.get("model") is None and r.get("model_error") == MODELLING]
    return found


def unfinished_jobs(store: StorePort) -> list[dict[str, Any]]:
    """The stored jobs a previous daemon left running (on the store)."""
    return _jobs(store).list_jobs(state="running", limit=RESUME_SCAN)
