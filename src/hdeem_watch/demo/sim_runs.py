"""The demo's runs on the simulated node without sockets or wall time: the benchmark's and the tests' node.

:class:`SimRuns` drives a real :class:`~hdeem_watch.sources.sim.SimSource` on a fake clock through
the demo's schedule (:func:`hdeem_watch.demo.schedule.demo_round`: an idle run and seven kernels per
round at 24, 4, 12 and 1 threads), measures every run's window the way the daemon does (the
difference of the sensors' cumulative energies between the polls at its start and its stop), and
hands the finished run record to the daemon's own run modeller
(:class:`hdeem_watch.calibrate.run_model.RunModeller`: the node fit, the per-pair fits, the guard rail
and the drift detectors). So what it measures — residuals, intervals, alarms — is what the daemon of
``hdeem-watch demo`` would, on the sim's misspecified truth, only without the sockets.

The pace is sim time: ``gap_s`` between runs (the demo at ``--speed 60`` on a 2-core machine
manages about one run per 7 sim-seconds: its control round trips cost wall time, which the speed
turns into sim time; at ``--speed 1`` the gap is the schedule's 0.4 s).

Example:
    >>> runs = SimRuns(seed=1, gap_s=5.5)
    >>> done = runs.step()
    >>> done.record["kernel"], done.record["window_s"] > 0
    ('idle', True)
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hdeem_watch.calibrate.counter_model import currents_with_counters
from hdeem_watch.calibrate.drift import DriftAlarm
from hdeem_watch.calibrate.group_fits import source_groups
from hdeem_watch.calibrate.run_model import RunModeller
from hdeem_watch.counters.source import CounterSnapshot, window_counts
from hdeem_watch.demo.nodes import DEMO_NODES, DemoNode
from hdeem_watch.demo.schedule import ELEMENTS, DemoRun, demo_round
from hdeem_watch.run_record import RunRecord
from hdeem_watch.sim.counters import SimCounters
from hdeem_watch.sim.model import memspec_setting
from hdeem_watch.sources.base import RunEvent
from hdeem_watch.sources.sim import SimSource

#: Sim seconds between the demo's runs at ``--speed 60`` (994 runs in 2 sim-hours, measured).
DEMO_GAP_S = 5.5
#: The demo's window tails at ``--speed 60`` (see :class:`SimRuns`): mostly 0.1–0.6 sim-s, one run in
#: ten 1–3 s.
DEMO_TAIL_S = (0.1, 0.6, 0.1, 1.0, 3.0)
_T0_WALL_NS = 1_700_000_000 * 10**9


@dataclass(frozen=True)
class FinishedRun:
    """One run as the daemon saw it.

    Attributes:
        index: run number (from 1).
        t_s: sim time of its stop (s since the sim opened).
        record: the daemon's run record (``energy_j`` per channel, ``window_s``, kernel, ...).
        model: the modeller's ``model`` entry (predictions, the groups' rows).
        error: why it was not fitted (None: fitted).
        alarms: the alarms this run raised.
    """

    index: int
    t_s: float
    record: dict[str, Any]
    model: dict[str, Any] | None
    error: str | None
    alarms: tuple[DriftAlarm, ...] = field(default_factory=tuple)


class SimRuns:
    """The demo's schedule on a sim node, measured and modelled as by the daemon (module docstring).

    Args:
        seed: the sim's seed.
        age: ``{pair: relative growth per sim hour}`` (``--sim-age``).
        age_start_s: ``{pair: sim s}`` when each pair starts to age.
        gap_s: sim seconds between runs.
        memspec: the model's memspec (None: the simulated node's own, as the daemon takes it).
        half_life_s: the calibrators' forgetting half-life (None: the daemon's default, never).
        sim_options: further :class:`SimSource` keyword arguments.
        tail_s: how much longer than its traffic a run's window is, drawn per run: ``(low, high,
            share, long_low, long_high)`` = U(low, high), and with probability ``share``
            U(long_low, long_high) instead. The demo's windows end at the daemon's first poll after
            ``run.stop`` and the control round trips cost wall time, both × the speed: at
            ``--speed 60`` (polls every 2.4 sim-s) the windows of 1.25–1.75 s runs came out
            1.4–5 s (:data:`DEMO_TAIL_S`). None: exact windows.
        seed_tail: seeds the tails.
        counters: count every run's commands with the sim's memory-controller counters (the
            daemon's ``counters = "sim"``; its rows then come from them).
        holdout: add the demo's hold-out runs (predicted, never fitted).
        groups: fit the sensor groups too (False: the node fit only, faster).
        node: the simulated node and its rounds' thread counts (default: the Haswell node).
    """

    def __init__(self, seed: int, *, age: Mapping[str, float] | None = None,
                 age_start_s: Mapping[str, float] | None = None, gap_s: float = DEMO_GAP_S,
                 memspec: str | None = None, half_life_s: float | None = None,
                 sim_options: Mapping[str, Any] | None = None,
                 tail_s: tuple[float, float, float, float, float] | None = None, seed_tail: int = 0,
                 counters: bool = False, holdout: bool = False, groups: bool = True,
                 node: DemoNode | None = None) -> None:
        self.node = node or DEMO_NODES["haswell"]
        layout = self.node.layout
        self._mono_ns = 0
        self.holdout = holdout
        self.tail_s = tail_s
        self._tail_rng = np.random.default_rng([int(seed), int(seed_tail), 9973])
        self.sim = SimSource(seed=seed, clock=lambda: self._mono_ns, wall_clock=lambda: _T0_WALL_NS,
                             background_plans=False, age=dict(age or {}), age_start_s=dict(age_start_s or {}),
                             layout=layout, **dict(sim_options or {}))
        self.sim.open()
        self.gap_ns = round(gap_s * 1e9)
        infos = self.sim.channels()
        self.dram = tuple(i.name for i in infos if i.kind == "dram")
        rates = {i.name: float(i.rate_hz) for i in infos if i.kind == "dram"}
        self.counters = SimCounters(self.sim) if counters else None
        currents = ("idd0", "idd2n", "idd3n", "idd4r", "idd4w")
        sensor_groups = source_groups(self.sim, rates, 2, 4)
        self.modeller = RunModeller(memspec or memspec_setting(layout), topology=layout.topology,
                                    currents=currents_with_counters(currents) if counters else currents,
                                    half_life_s=half_life_s, groups=sensor_groups if groups else (),
                                    dram_rates_hz=rates, sockets=sensor_groups)
        if self.modeller.error is not None:
            raise RuntimeError(self.modeller.error)
        self._energy = dict(self.sim.poll().energy_j)
        self._schedule = self._demo_runs()
        self.index = 0

    @property
    def t_s(self) -> float:
        """Sim seconds since the node opened."""
        return self._mono_ns * 1e-9

    def _demo_runs(self) -> Iterator[DemoRun]:
        round_no = 0
        while True:
            rounds = self.node.thread_rounds
            yield from demo_round(rounds[round_no % len(rounds)], round_no, holdout=self.holdout,
                                  layout=self.node.layout)
            round_no += 1

    def _advance(self, seconds: float) -> dict[str, float]:
        self._mono_ns += max(0, round(seconds * 1e9))
        return dict(self.sim.poll().energy_j)

    def _tail(self) -> float:
        if self.tail_s is None:
            return 0.0
        low, high, share, long_low, long_high = self.tail_s
        if self._tail_rng.random() < share:
            return float(self._tail_rng.uniform(long_low, long_high))
        return float(self._tail_rng.uniform(low, high))

    def step(self) -> FinishedRun:
        """Wait the gap, hold the next run of the schedule, model it; the finished run."""
        run = next(self._schedule)
        start = self._advance(self.gap_ns * 1e-9)
        self.index += 1
        spec = run.spec
        run_id = f"r{self.index}"
        elements = 0 if spec.kernel == "idle" else (spec.elements or ELEMENTS)
        t_start = self._mono_ns
        count_start = None if self.counters is None else self.counters.read()
        self.sim.on_run(RunEvent("start", run_id, spec.kernel, spec.threads, elements, spec.repeat, t_start))
        stop = self._advance(run.seconds + self._tail())
        self.sim.on_run(RunEvent("stop", run_id, spec.kernel, spec.threads, elements, spec.repeat, self._mono_ns))
        counted = None if count_start is None else self._window_counters(count_start)
        energy = {c: stop[c] - start[c] for c in stop}
        window_s = (self._mono_ns - t_start) * 1e-9
        record = {"run_id": run_id, "state": "modelling", "name": f"{spec.kernel}-{spec.threads}t", "kernel": spec.kernel,
                  "threads": spec.threads, "elements": elements, "repeat": spec.repeat, "window_s": window_s,
                  "t_start_ns": _T0_WALL_NS + t_start, "t_stop_ns": _T0_WALL_NS + self._mono_ns,
                  "energy_j": energy, "dram_energy_j": sum(energy[c] for c in self.dram),
                  "metadata": {"simulated": True, "source": "demo", "modelled_s": round(run.seconds, 4),
                               **({"holdout": True} if run.holdout else {})}}
        if counted is not None:
            record["counters"] = counted
        model, _fit, error = self.modeller.evaluate(RunRecord.from_dict(record))
        return FinishedRun(self.index, self.t_s, record, model, error, tuple(self.modeller.take_alarms()))

    def _window_counters(self, start: CounterSnapshot) -> dict[str, Any]:
        """The run's counters record, as the daemon's :class:`CounterWindows` makes it."""
        assert self.counters is not None
        end = self.counters.read()
        table = self.counters.table
        return {"source": "sim", "generation": table.generation, "status": "ok", "ranks": self.counters.ranks,
                "refresh_complete": table.refresh_complete, "t_start_ns": start.t_ns, "t_end_ns": end.t_ns,
                "window_s": (end.t_ns - start.t_ns) / 1e9,
                "sensors": {c.name: c.sensor for c in self.counters.channels()},
                "channels": window_counts(start, end)}

    def until(self, t_s: float) -> Iterator[FinishedRun]:
        """Runs until the sim time reaches ``t_s``."""
        while self.t_s < t_s:
            yield self.step()
