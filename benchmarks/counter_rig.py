"""A simulated node with memory counters under the daemon's real core, on a fake clock (a test rig).

The run book, operations, store worker and model worker of the daemon, the sim as the power source
and :class:`~hdeem_watch.sim.counters.SimCounters` as the counter source, wired as
``Daemon.poll_once`` wires them (counters read at the heartbeat, at window edges and until a closing
window's end; their deltas attached to the closed run). No sockets, no threads of its own beyond
the daemon's two workers; the core is wired by
:func:`~hdeem_watch.daemon.compose.build_node`, as the daemon's is. Used by the counter tests, the node-topology tests (a sim with a node
description, without counters) and by ``benchmarks/bench_counters.py``.

Example:
    >>> rig = CounterSimNode(Path("/tmp/rig-doctest"))          # doctest: +SKIP
    >>> rig.run(None, threads=12, seconds=5.0)["model"]["source"]  # doctest: +SKIP
    'counters'
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from hdeem_watch.daemon.book.runs import RunLimits
from hdeem_watch.daemon.book.state import NodeState
from hdeem_watch.daemon.compose import NodePorts, build_node
from hdeem_watch.daemon.counters.windows import CounterWindows
from hdeem_watch.daemon.ops.reporting import Identity
from hdeem_watch.daemon.shell.control import Pending
from hdeem_watch.daemon.shell.workers import ModelSettings, Worker, restore_calibration
from hdeem_watch.daemon.store.database import Store
from hdeem_watch.daemon.store.worker import StoreWorker
from hdeem_watch.dram.node import NodeTopology
from hdeem_watch.sim.counters import SimCounters
from hdeem_watch.sources.sim import SimSource

MEMSPEC = "samsung-m393a1g43db0-cpb"
POLL_NS = 50_000_000
WALL0 = 1_700_000_000 * 10**9


class _ListPublisher:
    """A publisher that keeps what it is given."""

    def __init__(self, published: list[tuple[str, Any]]) -> None:
        self.published = published

    def publish(self, kind: str, body: Any, *, t_ns: int | None = None) -> bool:
        self.published.append((kind, body))
        return True


class CounterSimNode:
    """The daemon's core over a simulated node with sim counters.

    Args:
        state_dir: where its SQLite store lives.
        seed: the sim's seed.
        counters: with the sim's counters (False: the kernel model only).
        realistic: the sim's sensor effects (noise, 0.125 W steps, offsets, gains, temperature);
            False: an exact signal.
        currents: the currents the calibrator fits.
        node: the simulated node's description (``SimSource(node=...)``; None: the Taurus blade).
        topology: the topology the daemon models runs on (None: the legacy guess from 8 DIMMs).
    """

    def __init__(self, state_dir: Path, *, seed: int = 3, counters: bool = True, realistic: bool = False,
                 currents: tuple[str, ...] = ("idd0", "idd2n", "idd3n", "idd4r", "idd4w"), node: Any = None,
                 topology: NodeTopology | None = None) -> None:
        self.now = 10 * POLL_NS
        quiet: dict[str, Any] = {} if realistic else {"noise": False, "quantum_w": 0.0, "offsets": False,
                                                      "gains": False, "temp_amp_c": 0.0}
        self.sim = SimSource(seed=seed, clock=lambda: self.now, wall_clock=self.wall, background_plans=False, node=node,
                             **quiet)
        self.sim.open()
        self.store = Store(state_dir / "state.db")
        self.book = NodeState(self.sim.channels(), node="n1", monotonic=lambda: self.now, wall=self.wall,
                              next_seq=1, limits=RunLimits(256, 1 << 34), baselines={})
        self.writer = StoreWorker(self.store)
        self.models = Worker("model")
        self.replies: dict[int, tuple[Any, Any]] = {}
        self.published: list[tuple[str, Any]] = []
        self.counters = SimCounters(self.sim) if counters else None
        self.windows = None
        if self.counters is not None:
            self.windows = CounterWindows("sim", table_key="haswell-ep", ranks=self.counters.ranks,
                                          refresh_complete=self.counters.table.refresh_complete,
                                          sensors={c.name: c.sensor for c in self.counters.channels()})
        ports = NodePorts(store=self.writer, submit=self.models.submit, publisher=_ListPublisher(self.published),
                          reply=self.reply, poll=self.edge_poll)
        self.core = build_node(self.book, self.sim, lambda: self.now, ports, identity=Identity(kind="sim", endpoints={}),
                               poll_interval_ns=lambda: POLL_NS,
                               observers=[self.attach] if self.windows is not None else [])
        self.calibration, self.reporter, self.ops = self.core.calibration, self.core.reporter, self.core.operations
        if self.windows is not None:
            self.read_counters(force=True)
        restore_calibration(self.calibration, settings=ModelSettings(MEMSPEC, topology=topology, max_requests=100_000,
                                                                     currents=currents),
                            state=None, fits=[], submit=self.models.submit, on_built=self.reporter.publish_calib)

    def wall(self) -> int:
        return WALL0 + self.now

    def reply(self, pending: Pending, result: Any, error: Any) -> None:
        self.replies[id(pending)] = (result, error)

    def read_counters(self, force: bool = False) -> None:
        assert self.windows is not None and self.counters is not None
        if force or self.windows.due(self.now, self.book.windows):
            self.windows.observe(self.counters.read(), now_mono_ns=self.now)
        if self.book.windows:
            self.windows.track(self.book.windows, self.book.sample_time_of)

    def attach(self, closed: Any) -> None:
        assert self.windows is not None
        if closed.run is not None and closed.run.state != "aborted":
            closed.run.counters = self.windows.finish(closed.run, self.book.dram_channels)

    def poll(self, force_counters: bool = False) -> None:
        _fresh, closed = self.book.on_batch(self.sim.poll())
        if self.windows is not None:
            self.read_counters(force=force_counters or bool(closed))
        for window in closed:
            self.core.window_closed(window)

    def edge_poll(self) -> None:
        self.poll(force_counters=True)

    def advance(self, seconds: float) -> None:
        for _ in range(max(1, math.ceil(seconds * 1e9 / POLL_NS))):
            self.now += POLL_NS
            self.poll()

    def settle(self) -> None:
        while self.models.pending or self.writer.pending:
            for worker in (self.models, self.writer.jobs):
                for future, _done, _failed in list(worker.pending):
                    future.exception(timeout=120)
                worker.collect()

    def call(self, op: str, args: dict[str, Any]) -> Any:
        result = self.ops.handlers()[op](args)
        if not isinstance(result, Pending):
            return result
        for _ in range(2000):
            self.settle()
            if id(result) in self.replies:
                value, error = self.replies.pop(id(result))
                assert error is None, error
                return value
            self.advance(POLL_NS / 1e9)
        raise AssertionError(f"{op}: no reply")

    def run(self, kernel: str | None, threads: int, elements: int = 0, repeat: int = 1,
            seconds: float | None = None, cpus: list[int] | None = None) -> dict[str, Any]:
        """One run (``kernel=None``: an opaque job of ``seconds``); the ``run.stop`` result. ``cpus``:
        the CPUs it announces in its metadata, as ``hdeem-watch bench`` does (None: none)."""
        args: dict[str, Any] = {"threads": threads, "elements": elements, "repeat": repeat}
        if kernel is not None:
            args["kernel"] = kernel
        if cpus is not None:
            args["metadata"] = {"cpus": cpus}
        started = self.call("run.start", args)
        if seconds is None:
            plan = self.sim.run_plan(started["run_id"]) if kernel not in (None, "idle") else None
            seconds = (plan.duration_ns * 1e-9 if plan is not None else 1.0) + 0.2
        self.advance(seconds)
        return dict(self.call("run.stop", {"run_id": started["run_id"]}))

    def close(self) -> None:
        self.models.shutdown(cancel_queued=True)
        self.writer.shutdown()
        self.store.close()
