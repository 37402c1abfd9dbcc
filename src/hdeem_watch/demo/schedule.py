"""The demo's benchmark schedule: announces runs to the sim node and holds each for its modelled time.

The simulated node does the memory traffic itself; the schedule only tells the daemon what runs
(``run.start`` with kernel, threads, elements, repeat, ``metadata.simulated = true`` and, as
``hdeem-watch bench`` does, ``metadata.cpus``: the CPUs the simulated threads run on, socket 0's
cores first (:func:`sim_cpus`, on the node ``node.get`` describes)), waits the
time the modelled node needs for it, and says ``run.stop``. ``repeat`` is chosen so a run lasts
about its target length with :func:`hdeem_watch.sources.sim.modelled_line_rate`.

The design is what makes the five currents identifiable within a minute (about 30 runs):

- thread counts 24, 4, 12, 1 (:data:`THREAD_ROUNDS`; on the DDR5 node 112, 16, 72, 1:
  :mod:`hdeem_watch.demo.nodes`): the share of row misses per line (IDD0)
  and the split between the sockets change with the threads;
- run lengths that vary (:data:`RUN_LENGTHS_S`, 1.25–1.75 s, the mean :data:`TARGET_RUN_S`): with
  every run equally long the standby power × window and the fit's intercept (a fixed energy per
  run) are the same column;
- an idle run (kernel ``idle``) per round, of a different length each round
  (:data:`IDLE_SECONDS`): it pins the precharge standby current and the intercept.

From the fifth round on (every thread count seen once) each round ends with a **hold-out** run: one
of :data:`hdeem_watch.dram.kernels.HOLDOUT_KERNELS` (GUPS-like random reads, a pointer chase, 2- and
4-line strides, a 3:1 read/write mix) at the round's thread count, announced with
``metadata.holdout = true``: the daemon predicts it with the fit from before it and never fits it.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from hdeem_watch.bench.schedule import IDLE_KERNEL, KERNELS, RunSpec, sweep
from hdeem_watch.demo.nodes import DEMO_NODES, DemoNode
from hdeem_watch.dram.kernels import HOLDOUT_KERNELS, kernel_traffic
from hdeem_watch.dram.node import HASWELL_EP, NodeTopology
from hdeem_watch.sim.layout import TAURUS, SimLayout
from hdeem_watch.sources.sim import modelled_line_rate
from hdeem_watch.wire.client import ControlClient, ControlError, DaemonUnreachable

#: Mean duration of one run, seconds.
TARGET_RUN_S = 1.5
#: Lengths of the kernel runs, cycled over the runs (mean TARGET_RUN_S). None shorter than 1.25 s:
#: the daemon fits a run only with 100 samples (1 s at 100 Sa/s) of every pair, and a 1.0 s target
#: came out at 0.96–1.0 s (99 samples) a third of the time.
RUN_LENGTHS_S = (1.25, 1.75, 1.5)
#: Length of the idle run of each round, cycled over the rounds (≥ 1.25 s, as above).
IDLE_SECONDS = (1.25, 3.0, 1.5, 2.25)
#: Doubles per array (128 MiB arrays: far larger than any last-level cache).
ELEMENTS = 1 << 24
#: Thread counts of the rounds, cycled.
THREAD_ROUNDS = ("24", "4", "12", "1")
#: The first round with a hold-out run (after every thread count was fitted once).
HOLDOUT_FROM_ROUND = len(THREAD_ROUNDS)
#: Pause between runs, seconds (the plots show the steps).
GAP_S = 0.4
#: Pause after a run was stopped by someone else (the TUI's ``s`` key), wall-clock seconds: room
#: for the ``b`` key's 10 s idle baseline measurement.
PAUSE_AFTER_ABORT_S = 15.0
#: Wait before trying a run again that the daemon refused (``conflict``: a baseline measurement).
RETRY_S = 1.0


def repeat_for(kernel: str, threads: int, elements: int = ELEMENTS, target_s: float = TARGET_RUN_S,
               layout: SimLayout = TAURUS) -> int:
    """Passes that make a run last about ``target_s`` on the modelled node ``layout`` (1 for idle)."""
    rate = modelled_line_rate(kernel, threads, layout=layout)
    if kernel == IDLE_KERNEL or rate <= 0:
        return 1
    traffic = kernel_traffic(kernel, elements)
    lines = traffic.lines_read + traffic.lines_written
    return max(1, round(target_s * rate / lines))


def run_seconds(spec: RunSpec, layout: SimLayout = TAURUS) -> float:
    """How long the modelled node ``layout`` needs for ``spec`` (``TARGET_RUN_S`` for an idle run)."""
    rate = modelled_line_rate(spec.kernel, spec.threads, spec.elements or ELEMENTS, layout)
    if spec.kernel == IDLE_KERNEL or rate <= 0:
        return TARGET_RUN_S
    traffic = kernel_traffic(spec.kernel, spec.elements)
    return (traffic.lines_read + traffic.lines_written) * spec.repeat / rate


def sim_cpus(threads: int, topology: NodeTopology = HASWELL_EP) -> list[int] | None:
    """The CPUs ``threads`` simulated threads run on: socket 0's cores first, then socket 1's, in
    Linux's default numbering (CPU ``i`` on socket ``(i // cores_per_socket) % sockets``), the way the
    simulated node places them; ``None`` beyond one thread per core (the sim wraps them).

    Example:
        >>> sim_cpus(14)[-3:], sim_cpus(25)
        ([11, 12, 13], None)
    """
    if not 1 <= int(threads) <= topology.sockets * topology.cores_per_socket:
        return None
    return list(range(int(threads)))


def node_topology(client: ControlClient) -> NodeTopology:
    """The daemon's node (``node.get``), or the Taurus Haswell-EP blade when it cannot say."""
    try:
        body = client.call("node.get")
        topo = body.get("topology") if isinstance(body, dict) else None
        if isinstance(topo, dict):
            return NodeTopology(sockets=int(topo["sockets"]), cores_per_socket=int(topo["cores_per_socket"]),
                                channels_per_socket=int(topo["channels_per_socket"]))
    except (ControlError, DaemonUnreachable, KeyError, TypeError, ValueError):
        pass
    return HASWELL_EP


@dataclass(frozen=True)
class DemoRun:
    """One run of the demo and how long to hold it.

    Attributes:
        spec: kernel, threads, elements, repeat.
        seconds: the time the modelled node needs for it (the chosen length for an idle run).
    """

    spec: RunSpec
    seconds: float
    holdout: bool = False


def demo_round(threads_spec: str, round_no: int = 0, *, holdout: bool = True,
               layout: SimLayout = TAURUS) -> list[DemoRun]:
    """Round ``round_no``: an idle run, then every kernel at each thread count of ``threads_spec``,
    then (``holdout``, from round :data:`HOLDOUT_FROM_ROUND`) one hold-out run (module docstring),
    sized for the simulated node ``layout``.

    The idle run lasts ``IDLE_SECONDS[round_no]`` (cycled); the kernel runs cycle through
    :data:`RUN_LENGTHS_S`, shifted by the round so each kernel gets different lengths.
    """
    idle = RunSpec(kernel=IDLE_KERNEL, threads=24, elements=0, repeat=1)
    runs = [DemoRun(idle, IDLE_SECONDS[round_no % len(IDLE_SECONDS)])]
    for i, spec in enumerate(sweep(list(KERNELS), threads_spec, ELEMENTS, 1)):
        target = RUN_LENGTHS_S[(i + round_no) % len(RUN_LENGTHS_S)]
        sized = RunSpec(spec.kernel, spec.threads, spec.elements,
                        repeat_for(spec.kernel, spec.threads, target_s=target, layout=layout))
        runs.append(DemoRun(sized, run_seconds(sized, layout)))
    if holdout and round_no >= HOLDOUT_FROM_ROUND:
        kernel = HOLDOUT_KERNELS[(round_no - HOLDOUT_FROM_ROUND) % len(HOLDOUT_KERNELS)]
        threads = int(str(threads_spec).split(",")[0])
        target = RUN_LENGTHS_S[round_no % len(RUN_LENGTHS_S)]
        sized = RunSpec(kernel, threads, ELEMENTS, repeat_for(kernel, threads, target_s=target, layout=layout))
        runs.append(DemoRun(sized, run_seconds(sized, layout), holdout=True))
    return runs


def demo_plan(rounds: int) -> list[DemoRun]:
    """The first ``rounds`` rounds, cycling through :data:`THREAD_ROUNDS`."""
    plan: list[DemoRun] = []
    for i in range(rounds):
        plan.extend(demo_round(THREAD_ROUNDS[i % len(THREAD_ROUNDS)], i))
    return plan


@dataclass(frozen=True)
class ScheduleEvent:
    """What the schedule did (for the headless printer and tests).

    Attributes:
        index: run number (from 1).
        spec: the run.
        event: ``start``, ``stop``, ``aborted`` (stopped by someone else, e.g. the TUI's ``s``; the
            schedule pauses for :data:`PAUSE_AFTER_ABORT_S`), ``waiting`` (the daemon is busy with
            a baseline measurement; the run is tried again) or ``error``.
        detail: the run id, or the error.
        result: the ``run.stop`` result (None otherwise).
    """

    index: int
    spec: RunSpec
    event: str
    detail: str = ""
    result: Any = None


class DemoSchedule(threading.Thread):
    """Announces the demo's runs to one daemon until stopped.

    Args:
        control_endpoint: the daemon's control endpoint.
        speed: the sim's time factor (a run is held ``modelled time / speed``).
        on_event: called (in this thread) for each start/stop/error.
        max_runs: stop after this many runs (None: go on until :meth:`stop`).
        holdout: add the hold-out runs (:func:`demo_round`).
        node: the simulated node the daemon runs (its runs' sizes and the rounds' thread counts;
            default the Haswell node).
    """

    def __init__(
        self,
        control_endpoint: str,
        *,
        speed: float = 1.0,
        on_event: Callable[[ScheduleEvent], None] | None = None,
        max_runs: int | None = None,
        holdout: bool = True,
        node: DemoNode | None = None,
    ) -> None:
        super().__init__(name="hdeem-watch-demo-schedule", daemon=True)
        self.node = node or DEMO_NODES["haswell"]
        self.control_endpoint = control_endpoint
        self.speed = speed if speed > 0 else 1.0
        self.on_event = on_event or (lambda _event: None)
        self.max_runs = max_runs
        self.holdout = holdout
        self._halt = threading.Event()
        self.completed = 0
        self.topology = HASWELL_EP

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop after the current run (which is stopped at once)."""
        self._halt.set()
        if self.is_alive():
            self.join(timeout_s)

    def run(self) -> None:
        client = ControlClient(self.control_endpoint, timeout_s=10.0)
        index = 0
        round_no = 0
        try:
            self.topology = node_topology(client)
            while not self._halt.is_set():
                rounds = self.node.thread_rounds
                for run in demo_round(rounds[round_no % len(rounds)], round_no, holdout=self.holdout,
                                      layout=self.node.layout):
                    if self._halt.is_set() or (self.max_runs is not None and index >= self.max_runs):
                        return
                    index += 1
                    while not self._one(client, index, run) and not self._halt.is_set():
                        pass
                    self._halt.wait(GAP_S / self.speed)
                round_no += 1
        finally:
            client.close()

    def _one(self, client: ControlClient, index: int, run: DemoRun) -> bool:
        """Hold one run; False when the daemon was busy and the run should be tried again."""
        spec = run.spec
        metadata: dict[str, Any] = {"simulated": True, "source": "demo", "modelled_s": round(run.seconds, 4)}
        if run.holdout:
            metadata["holdout"] = True
        cpus = sim_cpus(spec.threads, self.topology)
        if cpus is not None:
            metadata["cpus"] = cpus
        args = {
            "name": f"{spec.kernel}-{spec.threads}t",
            "kernel": spec.kernel,
            "threads": spec.threads,
            "elements": spec.elements,
            "repeat": spec.repeat,
            "metadata": metadata,
        }
        try:
            started = client.call("run.start", args)
        except ControlError as error:
            if error.code != "conflict":
                self.on_event(ScheduleEvent(index, spec, "error", str(error)))
                self._halt.wait(RETRY_S)
                return True
            self.on_event(ScheduleEvent(index, spec, "waiting", str(error)))
            self._halt.wait(RETRY_S)
            return False
        except DaemonUnreachable as error:
            self.on_event(ScheduleEvent(index, spec, "error", str(error)))
            self._halt.wait(RETRY_S)
            return True
        run_id = started.get("run_id") if isinstance(started, dict) else started
        self.on_event(ScheduleEvent(index, spec, "start", str(run_id)))
        self._halt.wait(run.seconds / self.speed)
        try:
            result = client.call("run.stop", {"run_id": run_id})
        except (ControlError, DaemonUnreachable) as error:
            self.on_event(ScheduleEvent(index, spec, "error", str(error)))
            self._halt.wait(RETRY_S)
            return True
        if isinstance(result, dict) and result.get("state") == "aborted":  # stopped by someone else
            self.on_event(ScheduleEvent(index, spec, "aborted", str(run_id), result))
            self._halt.wait(PAUSE_AFTER_ABORT_S)
            return True
        self.completed += 1
        self.on_event(ScheduleEvent(index, spec, "stop", str(run_id), result))
        return True
