"""The one composition root of a node's core: run book, reporter, ops and the window router, wired once.

:func:`build_node` takes the pure run book, the power source and the ports the shell provides
(the store worker, the model worker, the publisher, deferred replies, a poll at a window edge) and
returns the :class:`NodeCore`: every part is given what it needs when it is made, and the closed
windows go through one :class:`~hdeem_watch.daemon.ops.router.WindowRouter` keyed by window kind.
The daemon (:class:`~hdeem_watch.daemon.shell.service.Daemon`), the socket-free test nodes and the
counter benchmark's rig build their node here, so they run the same wiring.

Example:
    >>> sorted(NodeCore.__dataclass_fields__)
    ['book', 'calibration', 'job_ops', 'operations', 'reporter', 'router']
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

from hdeem_watch.daemon.book.state import ClosedWindow, NodeState
from hdeem_watch.daemon.counters.windows import CounterWindows
from hdeem_watch.daemon.jobs.book import JobBook
from hdeem_watch.daemon.jobs.records import job_summary
from hdeem_watch.daemon.ops.jobs import CHECKPOINT_S, JobOperations
from hdeem_watch.daemon.ops.node import Operations
from hdeem_watch.daemon.ops.ports import PublisherPort, Reply, Submit
from hdeem_watch.daemon.ops.reporting import Identity, Reporter
from hdeem_watch.daemon.ops.router import WindowRouter
from hdeem_watch.daemon.shell.control import Handler
from hdeem_watch.daemon.shell.workers import Calibration
from hdeem_watch.daemon.store.worker import StoreWorker
from hdeem_watch.sources.base import Source

Clock = Callable[[], int]


@dataclass(frozen=True)
class NodePorts:
    """What the shell gives a node's core.

    Attributes:
        store: the store worker (every database call, off the poll loop).
        submit: runs a job on the model worker (run models and refits) and calls back on the loop.
        publisher: the ``run``, ``job``, ``status``, ``calib`` and ``baseline`` topics.
        reply: sends a deferred control reply.
        poll: polls the source once now (a tight window edge; counters read too).
    """

    store: StoreWorker
    submit: Submit
    publisher: PublisherPort
    reply: Reply
    poll: Callable[[], object]


@dataclass(frozen=True)
class NodeCore:
    """A node's core, wired: what the poll loop and the control server drive."""

    book: NodeState
    calibration: Calibration
    reporter: Reporter
    operations: Operations
    job_ops: JobOperations
    router: WindowRouter

    def handlers(self) -> dict[str, Handler]:
        """Every control op of the core (run, baseline, calibration, query and job ops) by name."""
        return self.operations.handlers() | self.job_ops.handlers()

    def window_closed(self, closed: ClosedWindow) -> None:
        """Hand one window the run book closed to its observers and owner."""
        self.router(closed)


def build_node(book: NodeState, source: Source, clock: Clock, ports: NodePorts, *, identity: Identity,
               poll_interval_ns: Callable[[], int], calibration: Calibration | None = None,
               counter_windows: CounterWindows | None = None,
               observers: Iterable[Callable[[ClosedWindow], None]] = (),
               checkpoint_s: float = CHECKPOINT_S) -> NodeCore:
    """Wire a node's core over ``book`` and ``source``.

    Args:
        book: the node's run book.
        source: the power source (told about runs when it is run-aware).
        clock: monotonic ns (the book's clock).
        ports: what the shell provides.
        identity: what the status body says of this daemon.
        poll_interval_ns: the poll period now (the status body's).
        calibration: the calibration (None: a new, empty one; restore it with
            :func:`~hdeem_watch.daemon.shell.workers.restore_calibration`).
        counter_windows: the memory-controller counter windows jobs count with (None: no counters).
        observers: called first with every closed window (the counter feed attaches a run's counts).
        checkpoint_s: how often an open job's record is stored.
    """
    calibration = calibration if calibration is not None else Calibration()
    router = WindowRouter(observers)
    reporter = Reporter(book, calibration, source, ports.publisher, ports.store, identity,
                        poll_interval_ns=poll_interval_ns, clock=clock)
    job_ops = JobOperations(JobBook(book, counters=counter_windows), store=ports.store, publisher=ports.publisher,
                            reply=ports.reply, poll=ports.poll, checkpoint_s=checkpoint_s,
                            submit=ports.submit, calibration=calibration, dispatch=router)
    operations = Operations(book, calibration=calibration, reporter=reporter, store=ports.store,
                            publisher=ports.publisher, source=source, submit=ports.submit,
                            reply=ports.reply, poll=ports.poll, dispatch=router,
                            open_jobs=lambda: [job_summary(r.to_dict()) for r in job_ops.jobs.snapshots()])
    router.route("run", operations.window_closed)
    router.route("baseline", operations.window_closed)
    router.route("job", job_ops.window_closed)
    return NodeCore(book, calibration, reporter, operations, job_ops, router)
