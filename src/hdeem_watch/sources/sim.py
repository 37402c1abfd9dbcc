"""The simulated node: the embedded default source (HDEEM's channels on a modelled Haswell-EP node).

The node and its model are described in :mod:`hdeem_watch.sim.model`. This module is the
time shell: it turns the model into HDEEM-like samples — BLADE at 1000 Sa/s, CPU0/CPU1 and the four
DIMM pairs at 100 Sa/s, in steps of 0.125 W — and reacts to the runs the daemon announces
(:meth:`SimSource.on_run`).

Time: the sim's time runs ``speed`` × the injected monotonic clock since :meth:`SimSource.open`.
Sample timestamps are ``wall-clock at open + sim time`` (so at ``speed`` 1 they follow the wall
clock; at ``speed`` 10 they run ten times faster and the channel rates hold in timestamp time). A
sample at ``t`` is the mean power over ``(t − 1/rate, t]``. ``poll()`` returns exactly the samples
whose interval ended since the previous poll — nothing is invented after a stall; if the poller was
late by more than ``buffer_s`` (the sensor buffer), the older samples are lost (counted in
``SourceBatch.gaps``, status ``"gap"``) but their energy still enters the cumulative ``energy_j``
(like HDEEM's energy totals). ``energy_j`` is the integral of the published (quantised) samples
plus that of lost ones.

The hidden truth comes from the sim's own generator (:mod:`hdeem_watch.sim.plan`), not
from the daemon's model path, and has what real DIMMs do that the model leaves out: its own page
placement, channel and bank hash (other row-hit rates), power-down after idle time, refresh twice as
often above 85 °C, I/O energy per burst, a part per DIMM pair (±10 % currents), a gain and offset
per sensor, Gaussian noise, 0.125 W quantisation, and optionally aging of a pair
(``age={"DDR_CD": 0.30}`` = +30 %/h of sim time; the CLI form ``DDR_CD=+30%/h`` is parsed by
:func:`~hdeem_watch.sim.age.parse_sim_age`). :meth:`SimSource.truth` reports it all.

Example:
    >>> t = [0]
    >>> sim = SimSource(seed=3, clock=lambda: t[0], wall_clock=lambda: 0)
    >>> sim.open(); t[0] = 50_000_000
    >>> b = sim.poll()
    >>> len(b.samples["BLADE"][0]), len(b.samples["DDR_AB"][0])
    (50, 5)
"""

from __future__ import annotations

import collections
import logging
import math
import time
from collections.abc import Callable, Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from hdeem_watch.dram.stats import CommandStats
from hdeem_watch.sim.age import check_pairs
from hdeem_watch.sim.commands import HiddenCommands, array_stats, plan_end_ns
from hdeem_watch.sim.counters import SimCounters
from hdeem_watch.sim.currents import PartCurrents
from hdeem_watch.sim.fast import IdleBlocks, NoiseBank
from hdeem_watch.sim.jobs import JOB_KERNEL, JobPlan, job_plan
from hdeem_watch.sim.layout import TAURUS, SimLayout, layout_for_node
from hdeem_watch.sim.model import modelled_line_rate, socket_shares, threads_per_socket
from hdeem_watch.sim.plan import TruthNode
from hdeem_watch.sim.power import PowerPhysics, dimm_peak_w
from hdeem_watch.sim.signal import (
    NOISE_W,
    Plan,
    channel_power_w,
    deposit_owed,
    flat_power_w,
    mean_power_w,
)
from hdeem_watch.sim.truth import truth_report
from hdeem_watch.sources.base import STATUS_GAP, STATUS_OK, ChannelInfo, QuietLimit, RunEvent, SourceBatch

if TYPE_CHECKING:
    from hdeem_watch.node.description import NodeDescription

__all__ = ["SimSource", "modelled_line_rate", "socket_shares", "threads_per_socket"]

log = logging.getLogger(__name__)

#: How often (sim s) ``truth()`` runs the memspec check on the hidden currents again.
CHECK_EVERY_S = 60.0
#: Retired run plans kept to count their commands exactly at a window edge before they ended.
RETIRED_KEPT = 16


@dataclass
class _Pending:
    """A run whose plan a worker thread is computing."""

    future: Future[Plan]
    t0_ns: int
    event: RunEvent
    stop_ns: int | None = None


class SimSource:
    """The modelled Haswell-EP node with 8 DIMMs behind HDEEM's seven channels (or any other node).

    Args:
        seed: seeds the hidden currents, offsets and noise (deterministic for the same poll times).
        clock: monotonic clock in ns (the daemon's clock; ``RunEvent.t_mono_ns`` uses it too).
        speed: sim seconds per clock second.
        wall_clock: wall clock in ns (read once at open).
        noise: add Gaussian noise.
        quantum_w: quantisation step (0 = none).
        io_j_per_line: mean I/O energy per 64-byte line on the DIMM rails (VDDQ drivers and
            termination; not in the core model): reads 0.9×, writes 1.1× this. The default 0.5 nJ
            (≈ 1 pJ/bit) is a few % of the DIMMs' power under STREAM load.
        offsets: add a sensor offset per channel (DIMM pairs −0.1…+0.3 W, others ±1 W).
        aging_per_h: relative growth of every true current per sim hour (all pairs).
        temp_amp_c: amplitude of the DIMM temperature swing (°C, period 1 sim hour).
        dimm_spread: relative spread of the true currents between DIMMs (per current).
        buffer_s: sensor buffer (sim s): samples older than this at a poll are lost.
        background_plans: compute a run's energy plan (``kernel_stats``, seconds for big runs) in a
            worker thread; until it is ready the sim's sensors lag (samples after the run's start are
            held back, then delivered), so ``on_run`` never blocks the daemon's poll loop.
        block_s: while the node is idle, its samples are generated this far (sim s) ahead of the
            polls, in one computation per block (the hidden currents' drift is evaluated once per
            block: at 5 s their idle power steps by < 0.05 % at +30 %/h of aging); a run drops the
            unpublished rest at once. 0 = one block per poll (``benchmarks/bench_sim_poll.py``
            compares the default with 1-s blocks).
        layout: the node modelled (default :data:`~hdeem_watch.sim.layout.TAURUS`): its
            sockets, cores and channels; channels ``BLADE``, ``CPU<n>`` per socket and one
            ``DDR_<letters>`` sensor per pair of channels.
        node: a node description to model instead (one DIMM per channel); overrides ``layout``.
        age: ``{pair: relative growth per sim hour}`` of the DIMM pairs that age (0.30 = +30 %/h).
        age_start_s: ``{pair: sim s}`` when each pair's drift starts (default 0, the open).
        part_spread: relative spread of the parts, one factor on every current per DIMM pair.
        gains: give every sensor a gain (DIMM pairs ±3 %, others ±2 %); False = 1.
        ambient_c: the DIMMs' mean temperature (°C; above 85 °C refresh doubles).
        pd_entry_s: idle time after which the controller puts a rank into power-down.

    Example:
        >>> sim = SimSource(seed=1)
        >>> sim.truth()["simulated"]
        True
    """

    kind = "sim"

    def __init__(self, seed: int = 0, clock: Callable[[], int] = time.monotonic_ns, speed: float = 1.0,
                 wall_clock: Callable[[], int] = time.time_ns, *, noise: bool = True, quantum_w: float = 0.125,
                 io_j_per_line: float = 0.5e-9, offsets: bool = True, aging_per_h: float = 0.0,
                 temp_amp_c: float = 1.0, dimm_spread: float = 0.03, buffer_s: float = 60.0,
                 background_plans: bool = True, block_s: float = 5.0, layout: SimLayout = TAURUS,
                 node: NodeDescription | None = None, age: Mapping[str, float] | None = None,
                 age_start_s: Mapping[str, float] | None = None, part_spread: float = 0.10, gains: bool = True,
                 ambient_c: float = 40.0, pd_entry_s: float = PowerPhysics.pd_entry_s) -> None:
        if not speed > 0 or not math.isfinite(speed):
            from hdeem_watch.errors import InputError

            raise InputError(f"sim: speed = {speed!r}; expected a finite number > 0")
        self.seed = int(seed)
        self._clock = clock
        self._wall_clock = wall_clock
        self.speed = float(speed)
        self.noise = noise
        self.quantum_w = float(quantum_w)
        self.io_j_per_line = float(io_j_per_line)
        self.buffer_ns = int(buffer_s * 1e9)
        self.block_ns = max(0, int(block_s * 1e9))
        self.layout = layout_for_node(node) if node is not None else layout
        physics = PowerPhysics(io_read_j=0.9 * self.io_j_per_line, io_write_j=1.1 * self.io_j_per_line,
                               pd_entry_s=float(pd_entry_s))
        self.truth_node = TruthNode(self.seed, self.layout, physics)
        self.model = self.truth_node.model
        age = check_pairs(age or {}, self.layout.sensors)
        starts = {str(p).upper(): float(s) for p, s in (age_start_s or {}).items()}
        self.truth_model = PartCurrents(self.model.names, self.model.datasheet, self.seed, aging_per_h=aging_per_h,
                                        temp_amp_c=temp_amp_c, dimm_spread=dimm_spread, part_spread=part_spread,
                                        pairs=self.layout.dimm_sensor, age=age, age_start_s=starts,
                                        ambient_c=ambient_c)
        self._infos = channel_infos(self.layout)
        self._init_sensors(offsets=offsets, gains=gains)
        self._flat: dict[str, float] = {}
        self._flat_at = -1
        self._status_ok = {info.name: STATUS_OK for info in self._infos}
        #: Samples per channel that fit in the sensor buffer.
        self._buffer_k = {name: self.buffer_ns // period for name, period in self._period_ns.items()}
        #: The idle node's samples generated ahead (:mod:`hdeem_watch.sim.fast`).
        self._idle = IdleBlocks(self._groups, self._noise if noise else None, self.quantum_w, self.block_ns,
                                self._buffer_k)
        self._open = False
        self._t0_mono = 0
        self._t0_wall = 0
        #: the latest retired plans (to count exactly at a time before they ended), and the latest end
        #: of those no longer kept (no exact count before it)
        self._retired: collections.deque[Plan] = collections.deque(maxlen=RETIRED_KEPT)
        self._forgotten_until_ns = 0
        self._next_k: dict[str, int] = {}
        self._energy_j: dict[str, float] = {}
        self._plans: dict[str, Plan] = {}
        #: The DIMMs' hidden commands since open (the ground truth of the sim's IMC counters).
        self._hidden = HiddenCommands(self.truth_node.spec, len(self.layout.dimm_names),
                                      self.truth_model.temperature_c(0.0))
        self.background_plans = background_plans
        self._executor: ThreadPoolExecutor | None = None
        self._pending: dict[str, _Pending] = {}
        self._owed: dict[str, list[tuple[int, float]]] = {}  # channel -> [(sim ns, J)] to deposit
        self._sim_ns = 0
        self._generated_ns = 0
        #: (sim s, violations) of the latest memspec check of the truth (it changes only slowly)
        self._checked: tuple[float, dict[int, list[str]]] | None = None

    def _init_sensors(self, *, offsets: bool, gains: bool) -> None:
        """Each channel's sensor: its peak, offset, gain, noise and sample period, and the sample grids.

        Args:
            offsets: draw a sensor offset per channel (else 0 W).
            gains: draw a sensor gain per channel (else 1).
        """
        peak = dimm_peak_w(self.truth_node.spec)
        #: per DRAM pair its physical maximum (W); BLADE: the most its DIMMs can add (owed energy is
        #: deposited within these, never as a one-sample spike)
        self._peak_w = {info.name: peak * (len(self.layout.sensor_dimms(info.name)) if info.kind == "dram"
                                           else len(self.layout.dimm_names)) for info in self._infos}
        rng = np.random.default_rng([self.seed, 104729])
        self._offset_w = {
            info.name: (float(rng.uniform(-0.1, 0.3)) if info.kind == "dram" else float(rng.uniform(-1.0, 1.0)))
            if offsets else 0.0
            for info in self._infos
        }
        gain_rng = np.random.default_rng([self.seed, 104723])
        self._gain = {info.name: float(1.0 + gain_rng.uniform(-1.0, 1.0) * (0.03 if info.kind == "dram" else 0.02))
                      if gains else 1.0 for info in self._infos}
        self._noise = NoiseBank({info.name: np.random.default_rng([self.seed, i + 1]) for i, info in enumerate(self._infos)},
                                {info.name: NOISE_W[info.kind] for info in self._infos})
        self._period_ns = {info.name: round(1e9 / info.rate_hz) for info in self._infos}
        by_period: dict[int, list[ChannelInfo]] = {}
        for info in self._infos:
            by_period.setdefault(self._period_ns[info.name], []).append(info)
        #: Channels on the same sample grid, with their noise σ as a column (the idle fast path).
        self._groups = [(period, tuple(i.name for i in infos), np.array([[NOISE_W[i.kind]] for i in infos]))
                        for period, infos in by_period.items()]

    # -- Source protocol -------------------------------------------------------------------------------
    def channels(self) -> list[ChannelInfo]:
        """BLADE 1000 Sa/s; CPU0, CPU1, DDR_AB, DDR_CD, DDR_EF, DDR_GH 100 Sa/s (the default node)."""
        return list(self._infos)

    def open(self) -> None:
        """Start the node's clock (idempotent)."""
        if self._open:
            return
        self._t0_mono = int(self._clock())
        self._t0_wall = int(self._wall_clock())
        self._next_k = {info.name: 1 for info in self._infos}
        self._energy_j = {info.name: 0.0 for info in self._infos}
        self._sim_ns = 0
        self._generated_ns = 0
        self._hidden.settled[:] = 0.0
        self._idle.blocks = [None] * len(self._groups)
        self._flat_at = -1
        self._open = True

    def close(self) -> None:
        """Stop (idempotent); a closed sim can be opened again and starts afresh."""
        if self._open:
            self._idle.drop_all(self._next_k)
        self._open = False
        self._plans.clear()
        self._pending.clear()
        self._owed = {}
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None

    @property
    def quiet_limit(self) -> QuietLimit:
        """Unpolled, the simulated sensors keep ``buffer_s`` of samples (sim time), like HDEEM's buffer."""
        return QuietLimit(self.buffer_ns / 1e9)

    def health(self) -> str:
        """``"ok"`` when open, else ``"closed"``."""
        return "ok" if self._open else "closed"

    def sim_time_ns(self, t_mono_ns: int) -> int:
        """Sim time (ns since open) of a time on the injected monotonic clock."""
        elapsed = int(t_mono_ns) - self._t0_mono
        return elapsed if self.speed == 1.0 else round(elapsed * self.speed)

    def poll(self) -> SourceBatch:
        """Every sample whose interval ended since the previous poll (see the module docstring)."""
        if not self._open:
            raise RuntimeError("SimSource.poll() before open()")
        now = self._clock()
        elapsed = now - self._t0_mono
        sim_ns = elapsed if self.speed == 1.0 else round(elapsed * self.speed)
        if sim_ns < self._sim_ns:
            sim_ns = self._sim_ns
        self._sim_ns = sim_ns
        if self._pending:
            self._resolve_plans()
            # while a run's plan is being computed, the sensors lag: nothing after its start is generated
            sim_ns = min([sim_ns, *(p.t0_ns for p in self._pending.values())])
        sim_now = self._generated_ns = sim_ns if sim_ns > self._generated_ns else self._generated_ns
        samples: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        gaps: dict[str, int] = {}
        if not self._plans and not self._owed:   # the node is idle: slices of blocks generated ahead
            self._idle.poll(sim_now, self._t0_wall, self._next_k, self._energy_j, samples, self._flat_w)
        elif self._idle.any:
            self._idle.drop_all(self._next_k)
        status = dict(self._status_ok)
        if len(samples) < len(self._infos):
            self._poll_general(sim_now, samples, status, gaps)
        if self._plans:
            self._retire(sim_now)
        return SourceBatch(t_mono_ns=now, t_wall_ns=self._t0_wall + sim_now, samples=samples,
                           energy_j=dict(self._energy_j), status=status, gaps=gaps)

    def _poll_general(self, sim_now: int, samples: dict[str, tuple[np.ndarray, np.ndarray]],
                      status: dict[str, str], gaps: dict[str, int]) -> None:
        """Every channel not served from an idle block, computed for this poll alone (runs, lost stretches)."""
        idle = self._idle_w(sim_now)
        plans = list(self._plans.values())
        for info in self._infos:
            name, period = info.name, self._period_ns[info.name]
            if name in samples:
                continue
            offset, gain = self._offset_w[name], self._gain[name]
            k0, k1 = self._next_k[name], sim_now // period
            lost = 0
            if (k1 - k0 + 1) * period > self.buffer_ns:
                keep_from = k1 - self.buffer_ns // period + 1
                lost = keep_from - k0
                self._energy_j[name] += mean_power_w(name, k0 * period - period, (keep_from - 1) * period, idle,
                                                     plans, offset_w=offset, layout=self.layout, gain=gain) \
                    * (keep_from - k0) * period * 1e-9
                k0 = keep_from
            ks = np.arange(k0, k1 + 1, dtype=np.int64)
            t_end = ks * period
            power = channel_power_w(name, t_end, period, idle, plans, offset_w=offset, layout=self.layout, gain=gain)
            if name in self._owed:
                room = self._peak_w[name] - power if info.kind == "dram" else self._peak_w[name]
                keep = deposit_owed(self._owed[name], t_end, period, power, room)
                if keep:
                    self._owed[name] = keep
                else:
                    del self._owed[name]
            if self.noise and len(ks):
                power = power + self._noise.take(name, len(ks))
            if self.quantum_w > 0:
                power = np.round(power / self.quantum_w) * self.quantum_w
            power = np.maximum(power, 0.0)
            self._energy_j[name] += float(power.sum()) * period * 1e-9
            self._next_k[name] = k1 + 1
            samples[name] = (t_end + self._t0_wall, power)
            if lost:
                status[name] = STATUS_GAP
                gaps[name] = int(lost)

    def _flat_w(self, sim_now: int) -> dict[str, float]:
        """Every channel's noise-free idle power at ``sim_now`` (both groups' new blocks usually start together)."""
        if self._flat_at != sim_now:
            self._flat = flat_power_w(self._idle_w(sim_now), self._offset_w, self.layout, self._gain)
            self._flat_at = sim_now
        return self._flat

    def _idle_w(self, sim_ns: int) -> np.ndarray:
        """Every DIMM's true idle power (W) at ``sim_ns``."""
        t_s = sim_ns * 1e-9
        return self.truth_node.idle_power_w(self.truth_model.currents(t_s), self.truth_model.temperature_c(t_s))

    # -- runs ------------------------------------------------------------------------------------------
    def on_run(self, event: RunEvent) -> None:
        """Start or stop the load of a run (threads fill socket 0 first; energy conserved at stop)."""
        if not self._open:
            raise RuntimeError("SimSource.on_run() before open()")
        t = max(0, self.sim_time_ns(event.t_mono_ns))
        if event.kind == "start":
            # the traffic starts at t; what samples already published could not show is booked after them
            published = max(t, self._generated_ns)
            args = (self.truth_model.currents(t * 1e-9), self.truth_model.temperature_c(t * 1e-9), event.run_id, t,
                    event.kernel, int(event.elements), int(event.threads), int(event.repeat))
            if not self.background_plans:
                self._activate(self._make_plan(*args), published)
                return
            if self._executor is None:
                self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sim-plan")
            self._pending[event.run_id] = _Pending(self._executor.submit(self._make_plan, *args), published,
                                                   event)
        elif event.kind == "stop":
            t = max(t, self._generated_ns)   # the run's power is in what was published up to here
            pending = self._pending.get(event.run_id)
            if pending is not None:
                pending.stop_ns = t
                return
            self._stop(event.run_id, t)

    def _make_plan(self, currents: np.ndarray, temps_c: np.ndarray, run_id: str, t0_ns: int, kernel: str,
                   elements: int, threads: int, repeat: int) -> Plan:
        """A kernel run's plan, or an opaque job's hidden mix (kernel :data:`JOB_KERNEL`)."""
        if kernel == JOB_KERNEL:
            return job_plan(self.truth_node, currents, temps_c, run_id, t0_ns, threads=threads)
        return self.truth_node.plan(currents, temps_c, run_id, t0_ns, kernel, elements, threads, repeat)

    def _activate(self, plan: Plan, published_ns: int) -> None:
        """Make ``plan`` active; the DRAM energy its traffic drew before ``published_ns`` (in samples already
        published as idle) goes into the first sample after them."""
        self._plans[plan.run_id] = plan
        if plan.duration_ns <= 0 or published_ns <= plan.t0_ns:
            return
        if isinstance(plan, JobPlan):
            missed = plan.excess_energy_j(min(published_ns, plan.traffic_end_ns))
        else:
            missed = plan.excess_w * (min(published_ns, plan.traffic_end_ns) - plan.t0_ns) * 1e-9
        for d, pair in enumerate(self.layout.dimm_sensor):
            self._add_owed(pair, published_ns, float(missed[d]) * self._gain[pair])
        self._add_owed("BLADE", published_ns, float(missed.sum()) * self._gain["BLADE"])

    def _stop(self, run_id: str, t: int) -> None:
        plan = self._plans.get(run_id)
        if plan is None or plan.cpu_end_ns is not None:
            return
        stopped, owed = plan.stopped(t)
        self._plans[run_id] = stopped
        if np.any(owed > 0):
            for d, pair in enumerate(self.layout.dimm_sensor):
                self._add_owed(pair, t, float(owed[d]) * self._gain[pair])
            self._add_owed("BLADE", t, float(owed.sum()) * self._gain["BLADE"])

    def _resolve_plans(self, timeout_s: float | None = 0.0) -> None:
        """Move finished background plans into the active set (a failed plan = compute-only run)."""
        for run_id, pending in list(self._pending.items()):
            try:
                plan = pending.future.result(timeout=timeout_s)
            except FutureTimeout:
                continue
            except Exception as error:  # never let a model failure stop the sensors
                log.warning("sim: modelling run %s failed (%s); treating it as compute-only", run_id, error)
                ev = pending.event
                t_s = pending.t0_ns * 1e-9
                plan = self.truth_node.plan(self.truth_model.currents(t_s), self.truth_model.temperature_c(t_s), run_id,
                                            pending.t0_ns, "idle", 0, int(ev.threads), 1)
            del self._pending[run_id]
            self._activate(plan, pending.t0_ns)
            if pending.stop_ns is not None:
                self._stop(run_id, pending.stop_ns)

    def run_plan(self, run_id: str, timeout_s: float | None = None) -> Plan:
        """The energy plan of a run (waiting up to ``timeout_s`` for a background plan)."""
        if run_id in self._pending:
            self._resolve_plans(timeout_s)
        return self._plans[run_id]

    def truth(self) -> dict:
        """The hidden truth now — currents (A per device) per DIMM, per pair and averaged, the aging
        state, and which effects a node-level fit cannot absorb; simulation only
        (:func:`~hdeem_watch.sim.truth.truth_report`)."""
        t_s = self._sim_ns * 1e-9
        if self._checked is None or abs(t_s - self._checked[0]) > CHECK_EVERY_S:
            self._checked = (t_s, self.truth_node.physical_violations(self.truth_model.currents(t_s)))
        return truth_report(self.truth_node, self.truth_model, t_s, t_ns=self._t0_wall + self._sim_ns,
                            offset_w=self._offset_w, gain=self._gain, violations=self._checked[1])

    def sim_counters(self) -> SimCounters:
        """The memory-controller counters of this node (``counters = "sim"``)."""
        return SimCounters(self)

    # -- hidden commands (the ground truth of the memory-controller counters) ----------------------------
    def hidden_commands(self) -> tuple[int, list[CommandStats]]:
        """``(t_ns, per-DIMM statistics)``: every DIMM's cumulative hidden commands since open, at the
        latest sim time whose commands are known (like the sensors, they lag while a run's plan is
        being computed), ``t_ns`` on the samples' time axis (wall clock at open + sim time).

        DIMMs are in :attr:`layout` order (``layout.dimm_names``, socket-major).
        """
        if not self._open:
            raise RuntimeError("SimSource.hidden_commands() before open()")
        sim_ns = self._known_commands_ns()
        return self._t0_wall + sim_ns, self._hidden.at(sim_ns, self._plans.values())

    def hidden_commands_at(self, t_ns: int) -> list[CommandStats] | None:
        """Every DIMM's cumulative hidden commands at ``t_ns`` on the samples' time axis (an exact
        window edge for the memory-controller counters), or None when that time is not known yet (a
        run's plan is still being computed) or lies before the end of a retired run (its commands are
        folded into the settled totals)."""
        if not self._open:
            raise RuntimeError("SimSource.hidden_commands_at() before open()")
        sim_ns = int(t_ns) - self._t0_wall
        if sim_ns > self._known_commands_ns() or sim_ns < 0:
            return None
        total = self._hidden.array_at(sim_ns, self._plans.values())
        if sim_ns < self._forgotten_until_ns:
            return None  # a retired run no longer kept ended after that time
        for plan in (p for p in self._retired if plan_end_ns(p) > sim_ns):
            total = total - self._hidden.unsettled_at(sim_ns, plan)
        return [array_stats(values) for values in total]

    def _known_commands_ns(self) -> int:
        """The latest sim time whose commands are known (a pending plan holds it at its start)."""
        sim_ns = max(self._sim_ns, self.sim_time_ns(self._clock()))
        if self._pending:
            self._resolve_plans()
            sim_ns = min([sim_ns, *(p.t0_ns for p in self._pending.values())])
        return sim_ns

    # -- energy owed by stopped runs -------------------------------------------------------------------
    def _add_owed(self, name: str, t_ns: int, joules: float) -> None:
        self._owed.setdefault(name, []).append((t_ns, joules))

    def _retire(self, sim_now: int) -> None:
        for run_id, plan in list(self._plans.items()):
            if plan.cpu_end_ns is not None and plan.cpu_end_ns <= sim_now and plan.traffic_end_ns <= sim_now:
                self._hidden.settle(plan)
                if len(self._retired) == self._retired.maxlen:
                    self._forgotten_until_ns = max(self._forgotten_until_ns, plan_end_ns(self._retired[0]))
                self._retired.append(plan)
                del self._plans[run_id]


def channel_infos(layout: SimLayout) -> list[ChannelInfo]:
    """The sim's channels: BLADE at 1000 Sa/s, the CPU and DRAM channels at 100 Sa/s (HDEEM's rates)."""
    return ([ChannelInfo("BLADE", 1000.0, "blade")] + [ChannelInfo(n, 100.0, "cpu") for n in layout.cpu_channels]
            + [ChannelInfo(n, 100.0, "dram") for n in layout.sensors])
