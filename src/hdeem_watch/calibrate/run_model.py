"""The model side of a finished run, and the embedded online calibrator.

For a run of kernel K with T threads over N elements, repeated R times, the command statistics come
from :func:`hdeem_watch.dram.node.node_run_stats` on the node's topology (a
:class:`~hdeem_watch.dram.node.NodeTopology`, from the node description with
:func:`hdeem_watch.node.topology.topology_from_node`; default the Taurus Haswell-EP blade): the
traffic split of the node — each memory domain's threads load that domain's channels and DIMMs,
with XOR bank hashing; a domain without threads is idle — the same function the simulated node
uses. Where the threads ran: the CPU list the run announced (``metadata.cpus`` of ``run.start``,
sent by ``hdeem-watch bench``), else threads fill socket 0 first. The calibration row is
:func:`hdeem_watch.calibrate.rows.node_observation`: per domain
:func:`hdeem_watch.calibrate.observation_from_run` (background residency and refresh stretched to the
measured window, scaled by the domain's DIMMs), summed, against the node's total measured DRAM
energy. An idle run is a row with no commands. The row is added to the
:class:`~hdeem_watch.calibrate.OnlineCalibrator`, which refits.

The run's ``calibrated_j`` is a prediction: the model with the fit from *before* the run (so its
error is an honest out-of-sample error; ``fitted_j`` is the value after the refit). The ``calib``
body carries ``suggest``: the calibrator's ranking of the runs seen so far (and an idle run) by how
much one more of each would determine the weakest current
(:func:`hdeem_watch.calibrate.suggest_next`).

This class does no I/O (beyond one log line when the command source of the fitted rows changes)
and is used from ONE worker thread of the daemon (the fit and the kernel
model can take tens of milliseconds; the poll loop must not wait for them).

Example:
    >>> m = RunModeller("samsung-m393a1g43db0-cpb", dimms=8)   # doctest: +SKIP
    >>> model, fit, _ = m.evaluate(RunRecord.from_dict({
    ...     "run_id": "r1", "state": "modelling", "kernel": "idle", "threads": 1, "elements": 0, "repeat": 1,
    ...     "window_s": 10.0, "dram_energy_j": 200.0, "t_stop_ns": 0}))    # doctest: +SKIP
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from hdeem_watch.calibrate.counter_model import counter_groups, counters_model, cross_check, node_totals
from hdeem_watch.calibrate.group_fits import DEFAULT_MIN_SAMPLES, GroupFits
from hdeem_watch.counters.umc_energy import currents_basis
from hdeem_watch.dram.ddr5_channel import controller_spec
from hdeem_watch.errors import InputError
from hdeem_watch.run_record import NO_TRAFFIC_KERNELS, OPAQUE_KERNEL, RunRecord

if TYPE_CHECKING:
    from hdeem_watch.calibrate.drift import DriftAlarm
    from hdeem_watch.calibrate.group_rows import SensorGroup
    from hdeem_watch.dram.node import NodeTopology

log = logging.getLogger("hdeem_watch.daemon")

#: Compact fit-history entries kept for the ``calib`` topic.
MAX_HISTORY = 200
#: Runs not fitted whose reasons the ``calib`` body keeps.
MAX_SKIPPED = 200
#: Kinds of run kept as candidates for the suggested next run.
MAX_CANDIDATES = 64
#: Runs the daemon's calibrator keeps (the oldest are dropped first): its saved state stays small
#: (~2 KB per run) although it is rewritten at every stop.
MAX_CALIBRATION_RUNS = 256
#: Fits the calibrator keeps in its own history.
MAX_CALIBRATOR_HISTORY = 32
#: Highest plausible mean DRAM power per DIMM (W): DDR4 RDIMMs draw a few watts, ~15 W at most.
MAX_PLAUSIBLE_DIMM_W = 50.0

def announced_cpus(record: RunRecord) -> tuple[tuple[int, ...] | None, str]:
    """The CPU list a run announced (``metadata.cpus``), and where the placement comes from.

    A list that is not one non-negative integer per thread is ignored (with the reason), so a run
    is never modelled on a made-up placement.

    Example:
        >>> run = {"run_id": "r1", "state": "modelling", "threads": 2}
        >>> announced_cpus(RunRecord.from_dict({**run, "metadata": {"cpus": [28, 29]}}))
        ((28, 29), 'announced cpus')
        >>> announced_cpus(RunRecord.from_dict(run))[1]
        'default: no cpus announced; threads fill socket 0 first'
    """
    cpus = record.metadata.get("cpus")
    if cpus is None:
        return None, "default: no cpus announced; threads fill socket 0 first"
    threads = record.threads
    ok = (isinstance(cpus, list | tuple) and all(isinstance(c, int) and not isinstance(c, bool) and c >= 0 for c in cpus)
          and len(cpus) == threads)
    if not ok:
        return None, (f"default: metadata.cpus {str(cpus)[:80]!r} is not one CPU per thread ({threads!r}); "
                      "threads fill socket 0 first")
    return tuple(int(c) for c in cpus), "announced cpus"


def load_spec(memspec: str) -> Any:
    """A preset by name, or a DRAMPower JSON file: DDR4 (``MemSpec``) or DDR5 (``MemSpecDDR5``, one
    sub-channel; the ``memoryType`` of the file decides).

    Raises:
        InputError: unknown preset / unreadable file.
    """
    from hdeem_watch.dram.memspec import memspec_from
    from hdeem_watch.dram.memspec_ddr5 import ddr5_memspec

    ddr5 = ddr5_memspec(memspec)
    return ddr5 if ddr5 is not None else memspec_from(memspec)


def with_ranks(spec: Any, ranks: int | None) -> Any:
    """``spec`` with ``ranks`` ranks per DIMM (the node's DIMMs), unchanged when ``ranks`` is None."""
    if ranks is None or int(ranks) == int(spec.nbr_of_ranks):
        return spec
    import dataclasses

    return dataclasses.replace(spec, nbr_of_ranks=int(ranks))


def idle_stats(spec: Any) -> Any:
    """Command statistics with no commands (one empty rank per rank of ``spec``)."""
    from hdeem_watch.dram.stats import CommandStats, RankStats

    return CommandStats(ranks=tuple(RankStats() for _ in range(int(spec.nbr_of_ranks))))


def compact_fit(t_ns: int, fit: Mapping[str, Any] | None) -> dict[str, Any]:
    """One ``history`` entry of the ``calib`` topic."""
    if fit is None:
        return {"t_ns": int(t_ns), "runs": 0, "error_after": None, "currents": {}}
    currents = {name: entry.get("calibrated") for name, entry in (fit.get("currents") or {}).items()}
    return {
        "t_ns": int(t_ns),
        "runs": fit.get("n_runs"),
        "error_after": (fit.get("error") or {}).get("after"),
        "currents": currents,
    }


class RunModelResult(NamedTuple):
    """What modelling one finished run gives (it crosses from the model worker to the poll loop)."""

    #: The run's ``model`` body (None: the run could not be modelled).
    model: dict[str, Any] | None
    #: The refit's ``to_dict()`` (None: no refit).
    fit: dict[str, Any] | None
    #: Why the run was not modelled or not fitted (None: it was both).
    error: str | None


@dataclasses.dataclass(frozen=True)
class _Observed:
    """One run as the calibrator sees it, and what made it: its row, the command statistics per
    memory domain (counted or from the kernel model), where its CPUs came from."""

    obs: Any
    groups: list[tuple[Any, int]]
    kernel_groups: list[tuple[Any, int]] | None
    counted: bool
    counter_error: str | None
    counter_notes: list[str]
    cpus: tuple[int, ...] | None
    cpus_source: str
    run_name: str
    stop_ns: int
    traffic_s: float | None


class RunModeller:
    """Kernel model + calibrator of one node.

    Args:
        memspec: preset name or memspec file of one DIMM.
        dimms: DIMMs the node's DRAM channels cover (used only without ``topology``: the legacy
            guess :func:`~hdeem_watch.dram.node.topology_for`).
        topology: the node (:func:`hdeem_watch.node.topology.topology_from_node`); its DIMM
            count replaces ``dimms``, its ranks per DIMM (when known) the memspec's.
        currents: currents to calibrate.
        half_life_s: forgetting half-life (0 or None = never forget).
        physical_rules: keep the ordering rules between calibrated currents (the ``physical_rules``
            setting; applies from the next refit, also over a restored calibrator).
        max_requests: prefix size of the kernel model (None = its default).
        state: a saved :meth:`state` (``OnlineCalibrator.to_dict()``, with the groups' state under
            ``sensor_groups``) to continue from.
        history: saved compact history entries.
        groups: the node's sensor groups, each fitted on its own
            (:func:`hdeem_watch.calibrate.group_fits.source_groups`; none: the node fit only).
        dram_rates_hz: sample rate of each DRAM channel, for the guard rail (None: no guard rail;
            the daemon always gives them).
        min_samples: fewest samples per DRAM channel for a run to be fitted.
        trust: widen the node fit's intervals by what its rows do not know and hold currents
            without a state of their own (:mod:`hdeem_watch.calibrate.trust`).

    Attributes:
        error: why runs cannot be modelled (None = they can).
        group_fits: the per-group fits and the guard rail (None when the model is not available).
    """

    def __init__(
        self,
        memspec: str,
        *,
        dimms: int = 8,
        topology: NodeTopology | None = None,
        currents: Sequence[str] = ("idd0", "idd2n", "idd3n", "idd4r", "idd4w"),
        half_life_s: float | None = None,
        physical_rules: bool = False,
        max_requests: int | None = None,
        state: Mapping[str, Any] | None = None,
        history: Sequence[Mapping[str, Any]] = (),
        groups: Sequence[SensorGroup] = (),
        dram_rates_hz: Mapping[str, float] | None = None,
        min_samples: int = DEFAULT_MIN_SAMPLES,
        trust: bool = True,
    ) -> None:
        self.memspec = memspec
        self.dimms = int(topology.dimms) if topology is not None else int(dimms)
        self.currents = tuple(currents)
        self.half_life_s = half_life_s if half_life_s else None
        self.max_requests = max_requests
        self.error: str | None = None
        self.restore_error: str | None = None
        self.spec: Any = None
        #: the memspec of one channel as the controller model spells it (``dram.ddr5_channel.controller_spec``)
        self.channel_spec: Any = None
        self._said_currents = False
        self.calibrator: Any = None
        self.group_fits: GroupFits | None = None
        self.history: list[dict[str, Any]] = [dict(h) for h in history][-MAX_HISTORY:]
        #: runs the node fit did not take, and why (newest last)
        self.skipped: list[dict[str, Any]] = []
        self._source_said: str | None = None
        try:
            self.spec = with_ranks(load_spec(memspec), getattr(topology, "ranks_per_dimm", None))
            self.channel_spec = controller_spec(self.spec)
            from hdeem_watch.calibrate import OnlineCalibrator

            if state:
                try:
                    self.calibrator = OnlineCalibrator.from_dict(state, self.spec)
                except InputError as error:  # a state this version cannot read: start afresh
                    self.restore_error = str(error)
            if self.calibrator is None:
                self.calibrator = OnlineCalibrator(self.spec, currents=self.currents, half_life_s=self.half_life_s,
                                                   max_runs=MAX_CALIBRATION_RUNS,
                                                   max_history=MAX_CALIBRATOR_HISTORY)
            self.calibrator.rules = bool(physical_rules)
            from hdeem_watch.calibrate.trust import TrustOptions

            self.calibrator.trust = TrustOptions() if trust else None
            self.calibrator.max_runs = min(self.calibrator.max_runs, MAX_CALIBRATION_RUNS)
            self.calibrator.max_history = min(self.calibrator.max_history, MAX_CALIBRATOR_HISTORY)
            observations = self.calibrator.observations
            if len(observations) > self.calibrator.max_runs:  # a state saved by an unbounded daemon
                newest = sorted(range(len(observations)), key=lambda i: observations[i].time_ns)
                keep = set(newest[len(observations) - self.calibrator.max_runs:])
                self.calibrator.observations = [o for i, o in enumerate(observations) if i in keep]
            if topology is not None and topology.numa_nodes_per_socket != 1:
                groups = ()  # the model's rows are per NUMA domain, the groups' per socket
            self.group_fits = GroupFits(self.spec, groups, dram_rates_hz, min_samples=min_samples,
                                        calibrator={"currents": self.currents, "half_life_s": self.half_life_s,
                                                    "rules": bool(physical_rules)},
                                        state=(state or {}).get("sensor_groups"))
            if self.group_fits.restore_error and not self.restore_error:
                self.restore_error = self.group_fits.restore_error
        except ImportError as error:  # a model module not installed yet
            self.error = f"model not available: {error}"
        except InputError as error:
            self.error = str(error)
        self.topology: Any = topology
        self._candidates: dict[str, Any] = {}
        if self.error is None and self.topology is None:
            from hdeem_watch.dram.node import topology_for

            self.topology = topology_for(self.dimms)
        self._stats_cache = functools.lru_cache(maxsize=64)(self._kernel_stats)
        self._family_cache = functools.lru_cache(maxsize=64)(self._family_factors)

    def _kernel_stats(self, kernel: str, elements: int, threads: int, repeat: int,
                      cpus: tuple[int, ...] | None) -> Any:
        from hdeem_watch.dram.node import node_run_stats

        return tuple(node_run_stats(self.channel_spec, kernel, elements, threads, repeat, self.topology, cpus=cpus,
                                    max_requests=self.max_requests))

    def _family_factors(self, kernel: str, elements: int, threads: int, repeat: int,
                        cpus: tuple[int, ...] | None) -> tuple[float, ...]:
        from hdeem_watch.dram.node import MAPPING_FAMILIES, node_counts, node_run_stats

        own = node_counts(self._stats_cache(kernel, elements, threads, repeat, cpus))["act"]
        out = []
        for scheme, xor in MAPPING_FAMILIES[1:]:
            groups = node_run_stats(self.channel_spec, kernel, elements, threads, repeat, self.topology, cpus=cpus,
                                    max_requests=self.max_requests, mapping=scheme, xor_bank=xor)
            out.append(node_counts(groups)["act"] / own if own > 0 else 1.0)
        return tuple(out)

    def mapping_factors(self, kernel: str, elements: int, threads: int, repeat: int,
                        cpus: Sequence[int] | None = None) -> tuple[float, ...]:
        """The run's activation count under each other mapping family relative to the model's own
        (:data:`hdeem_watch.dram.node.MAPPING_FAMILIES`; cached; empty for a run without traffic)."""
        if kernel in NO_TRAFFIC_KERNELS or elements == 0:
            return ()
        return self._family_cache(kernel, int(elements), int(threads), int(repeat),
                                  None if cpus is None else tuple(int(c) for c in cpus))

    def groups_for(self, kernel: str, elements: int, threads: int, repeat: int,
                   cpus: Sequence[int] | None = None) -> list[tuple[Any, int]]:
        """Per memory domain (socket, or NUMA node under SNC), the modelled statistics of one of its
        DIMMs and how many DIMMs it has (cached; idle kernels and idle domains have no commands).

        Args:
            kernel, elements, threads, repeat: the run.
            cpus: the CPUs its threads were pinned to (None: threads fill socket 0 first).

        Raises:
            InputError: a CPU the node does not have, an unknown kernel.
        """
        if kernel in NO_TRAFFIC_KERNELS or elements == 0:
            from hdeem_watch.dram.node import idle_channel_stats

            idle = idle_channel_stats(self.channel_spec)
            return [(idle, self.topology.dimms_per_domain)] * self.topology.domains
        return list(self._stats_cache(kernel, int(elements), int(threads), int(repeat),
                                      None if cpus is None else tuple(int(c) for c in cpus)))

    def stats_for(self, kernel: str, elements: int, threads: int, repeat: int) -> Any:
        """Modelled statistics of one DIMM of socket 0 for a run (see :meth:`groups_for`)."""
        return self.groups_for(kernel, elements, threads, repeat)[0][0]

    def placement(self, threads: int, cpus: Sequence[int] | None, source: str) -> dict[str, Any]:
        """The ``model.placement`` entry: threads and DIMMs per memory domain, and where the CPUs came from."""
        topo = self.topology
        per_domain = topo.domain_threads(threads, cpus)
        return {"cpus": source, "domains": [
            {"socket": topo.socket_of_domain(d), "numa_node": d % topo.numa_nodes_per_socket, "threads": n,
             "dimms": topo.dimms_per_domain} for d, n in enumerate(per_domain)],
            "topology": {"sockets": topo.sockets, "cores_per_socket": topo.cores_per_socket,
                         "numa_nodes_per_socket": topo.numa_nodes_per_socket,
                         "channels_per_socket": topo.channels_per_socket,
                         "dimms_per_channel": topo.dimms_per_channel, "ranks_per_dimm": int(self.spec.nbr_of_ranks)}}

    def latest_fit(self) -> dict[str, Any] | None:
        """``FitResult.to_dict()`` of the latest fit, or None."""
        if self.calibrator is None or self.calibrator.latest is None:
            return None
        return dict(self.calibrator.latest.to_dict())

    def _currents_vector(self, fit: Mapping[str, Any] | None) -> tuple[np.ndarray, float]:
        from hdeem_watch.calibrate.observation import current_names

        names = current_names(self.spec)
        values = {n: float(self.spec.currents.get(n, 0.0)) for n in names}
        intercept = 0.0
        if fit is not None:
            for name, entry in (fit.get("currents") or {}).items():
                value = entry.get("calibrated")
                if name in values and isinstance(value, int | float) and math.isfinite(value):
                    values[name] = float(value)
            value = fit.get("intercept_j")
            intercept = float(value) if isinstance(value, int | float) and math.isfinite(value) else 0.0
        return np.array([values[n] for n in names]), intercept

    def evaluate(self, record: RunRecord) -> RunModelResult:
        """Model a finished run, add it to the calibrator and refit.

        Returns:
            :class:`RunModelResult` ``(model, fit, error)``: ``model`` = ``{"memspec", "dimms",
            "groups" (DIMMs per memory domain), "placement" (:meth:`placement`: where the CPUs came
            from, threads and DIMMs per domain, the topology), "datasheet_j", "predicted_j",
            "calibrated_j" (= predicted_j: the fit before this run), "fitted_j" (after the refit),
            "counts", "observation"}`` (None when the run cannot be modelled), ``fit`` = the refit's
            ``to_dict()`` (None without a refit) and ``error`` = why not.
        """
        if self.error is not None:
            return RunModelResult(None, None, self.error)
        name = record.name or record.run_id
        measured, window_s = record.dram_energy_j, record.window_s
        if (why := self._unmeasured(name, measured, window_s)) is not None:
            return RunModelResult(None, None, why)
        assert measured is not None and window_s is not None  # (_unmeasured said so)
        observed = self._observe(record, name, window_s, measured)
        if isinstance(observed, str):
            return RunModelResult(None, None, observed)
        model = self._model_body(record, observed, window_s, measured)
        return self._refit(record, observed, model)

    def _observe(self, record: RunRecord, name: str, window_s: float, measured: float) -> _Observed | str:
        """The run as one calibration row, from its counters or its kernel (a string: why it cannot be)."""
        from hdeem_watch.calibrate.rows import node_observation

        cpus, cpus_source = announced_cpus(record)
        run_name, stop_ns = f"{record.run_id}:{name}", record.t_stop_ns or 0
        opaque = record.kernel == OPAQUE_KERNEL
        counted, counter_error, counter_notes = self._counted(record)
        if opaque and counted is None:
            return f"run {name!r}: a job without a kernel is modelled from counters only: {counter_error}"
        kernel_groups = None
        if not opaque and None in (record.elements, record.threads, record.repeat):
            return f"run {name!r}: its threads, elements or repeat are unknown ({'; '.join(record.problems)})"
        try:
            if not opaque:
                kernel = (record.kernel, int(record.elements or 0), int(record.threads or 0), int(record.repeat or 0))
                try:
                    kernel_groups = self.groups_for(*kernel, cpus)
                except InputError as error:  # an announced CPU this node does not have: say so, model the default
                    if cpus is None:
                        raise
                    cpus, cpus_source = None, f"default: {error}; threads fill socket 0 first"
                    kernel_groups = self.groups_for(*kernel)
            groups = counted if counted is not None else kernel_groups
            assert groups is not None
            # A kernel's traffic lasts what the run announced; the window may run on past it (the stop is
            # seen at the next poll): the rest of the window is standby. Counters measure the window itself.
            traffic_s = record.traffic_s
            factors = () if counted is not None or opaque else self.mapping_factors(*kernel, cpus)
            obs = node_observation(self.spec, groups, window_s, measured, name=run_name, time_ns=stop_ns,
                                   traffic_s=traffic_s if counted is None else None,
                                   commands="model" if counted is None else "counters", act_factors=factors)
        except InputError as error:
            return str(error)
        return _Observed(obs, groups, kernel_groups, counted is not None, counter_error, counter_notes, cpus,
                         cpus_source, run_name, stop_ns, traffic_s)

    def _model_body(self, record: RunRecord, observed: _Observed, window_s: float,
                    measured: float) -> dict[str, Any]:
        """The run's ``model`` body: datasheet and calibrated predictions, counts, the kernel cross-check."""
        from hdeem_watch.calibrate.rows import node_observation
        from hdeem_watch.dram.node import node_counts

        obs, groups, kernel_groups = observed.obs, observed.groups, observed.kernel_groups
        before = self.latest_fit()
        datasheet_vec, _ = self._currents_vector(None)
        model: dict[str, Any] = {
            "source": "counters" if observed.counted else "kernel",
            "memspec": getattr(self.spec, "memory_id", self.memspec),
            "dimms": self.dimms,
            "groups": [n for _stats, n in groups],
            "placement": self.placement(record.threads or 0, observed.cpus, observed.cpus_source),
            "datasheet_j": obs.predicted_j(datasheet_vec),
            "predicted_j": None,
            "calibrated_j": None,
            "fitted_j": None,
            "counts": node_totals(groups) if observed.counted else node_counts(groups),
            "observation": obs.to_dict(),
        }
        if observed.counted:
            model["counter_estimates"] = observed.counter_notes
        elif observed.counter_error is not None:
            model["counter_error"] = observed.counter_error
        kernel_obs = None
        if observed.counted and kernel_groups is not None:
            kernel_obs = node_observation(self.spec, kernel_groups, window_s, measured, name=observed.run_name,
                                          time_ns=observed.stop_ns, traffic_s=observed.traffic_s)
            model["kernel_model"] = {**cross_check(model["counts"], node_counts(kernel_groups)),
                                     "datasheet_j": kernel_obs.predicted_j(datasheet_vec), "predicted_j": None}
        if before is not None:
            vec, intercept = self._currents_vector(before)
            model["predicted_j"] = model["calibrated_j"] = obs.predicted_j(vec, intercept)
            if kernel_obs is not None:
                model["kernel_model"]["predicted_j"] = kernel_obs.predicted_j(vec, intercept)
        return model

    def _refit(self, record: RunRecord, observed: _Observed, model: dict[str, Any]) -> RunModelResult:
        """Add the run's row to the calibrator and refit, unless it is a hold-out, guarded or known."""
        run_name, stop_ns, obs = observed.run_name, observed.stop_ns, observed.obs
        if record.holdout:
            return RunModelResult(model, None, self._skip(run_name, stop_ns, "hold-out run: predicted with the fit "
                                                                             "from before it, never fitted"))
        if self.group_fits is not None and (reason := self.group_fits.unmeasured(record)) is not None:
            return RunModelResult(model, None, self._skip(run_name, stop_ns, reason))  # the guard rail
        if self.has_run(record.run_id):  # modelled again after a crash: already in the fit
            return RunModelResult(model, None, "the calibrator already had this run (modelled again after a restart)")
        try:
            result = self.calibrator.add_run(obs)
        except InputError as error:
            return RunModelResult(model, None, self._skip(run_name, stop_ns, str(error)))
        self._say_source(run_name, model["source"], record)
        self._add_to_groups(model, record, observed.kernel_groups, observed.groups)
        fit = dict(result.to_dict())
        vec, intercept = self._currents_vector(fit)
        model["fitted_j"] = obs.predicted_j(vec, intercept)
        self._remember_candidate(record, obs)
        self.history.append(compact_fit(int(result.time_ns or obs.time_ns), fit))
        del self.history[:-MAX_HISTORY]
        return RunModelResult(model, fit, None)

    def _unmeasured(self, name: str, measured: Any, window_s: Any) -> str | None:
        """Why run ``name`` with ``measured`` J over ``window_s`` s cannot be calibrated (None: it can)."""
        if not isinstance(measured, int | float) or not math.isfinite(measured) or measured <= 0:
            return f"run {name!r}: no measured DRAM energy ({measured!r})"
        if not isinstance(window_s, int | float) or not math.isfinite(window_s) or not window_s > 0:
            return f"run {name!r}: empty window"
        if measured / window_s > MAX_PLAUSIBLE_DIMM_W * self.dimms:
            return (f"run {name!r}: implausible measured DRAM power {measured / window_s:.4g} W "
                    f"(more than {MAX_PLAUSIBLE_DIMM_W:g} W per DIMM); not calibrated")
        return None

    def _add_to_groups(self, model: dict[str, Any], record: RunRecord,
                       kernel_groups: list[tuple[Any, int]] | None, groups: list[tuple[Any, int]]) -> None:
        """Add a fitted run to the sensor-group fits (kernel runs only); say in ``model`` what they took or why not."""
        if self.group_fits is not None and kernel_groups is None:
            model["group_error"] = "a job without a kernel: the sensor groups are fitted on kernel runs only"
        elif self.group_fits is not None:
            try:
                model["group_observations"] = self.group_fits.add(record, kernel_groups or groups)
            except InputError as error:  # the node fit stands; say why the groups did not take the run
                model["group_error"] = str(error)

    def _say_source(self, run_name: str, source: str, record: RunRecord) -> None:
        """Log once, and again whenever it changes, where the fitted rows' commands come from."""
        if source == self._source_said:
            return
        self._source_said = source
        if source == "counters":
            where = (record.counters or {}).get("source", "?")
            log.info("calibration: rows from the commands counted in each run's window (counters = %s) from run "
                     "%s on; the kernel model is the cross-check", where, run_name)
        else:
            log.info("calibration: rows from the kernel model's commands (no counters) from run %s on; currents "
                     "that rest on its activations are not shown as determined", run_name)

    def _skip(self, name: str, time_ns: int, reason: str) -> str:
        """Keep why a run was not fitted (``node_skipped`` of the body); the reason."""
        self.skipped.append({"name": name, "time_ns": int(time_ns), "reason": reason})
        del self.skipped[:-MAX_SKIPPED]
        return reason

    def model_counters(self, counters: Mapping[str, Any] | None,
                       measured_j: Mapping[str, float] | None = None) -> tuple[dict[str, Any] | None, str]:
        """A SLURM job's modelled DRAM energy by component from its counters (not a calibration row:
        a job's window mixes whatever ran), with the datasheet and the latest fit's currents.

        Returns:
            ``(model, "")`` (:func:`~hdeem_watch.calibrate.counter_model.counters_model`, plus
            ``dimms``), or ``(None, why not)``.
        """
        if self.error is not None:
            return None, self.error
        if not isinstance(counters, Mapping):
            return None, "no counters recorded for this job"
        fit = self.latest_fit()
        datasheet, _ = self._currents_vector(None)
        calibrated, intercept = self._currents_vector(fit) if fit is not None else (None, 0.0)
        try:
            model = counters_model(self.spec, counters, datasheet_a=datasheet, calibrated_a=calibrated,
                                   intercept_j=intercept, measured_j=measured_j)
        except InputError as error:
            return None, str(error)
        model["memspec"] = getattr(self.spec, "memory_id", self.memspec)
        model.setdefault("currents", dataclasses.asdict(currents_basis(self.spec, self.memspec)))
        if not self._said_currents:  # once: which currents the jobs' counter model rests on
            self._said_currents = True
            log.info("jobs' DRAM energy from counters: %s", model["currents"]["text"])
        model["dimms"] = self.dimms
        model["fit_runs"] = None if fit is None else fit.get("n_runs")
        return model, ""

    def _counted(self, record: RunRecord) -> tuple[list[tuple[Any, int]] | None, str | None, list[str]]:
        """The window's per-channel statistics from its counters (None and why when it has none)."""
        counters = record.counters
        if not isinstance(counters, Mapping):
            return None, "no counters recorded (counters = 'none', or the window has no counter start)", []
        try:
            groups, notes = counter_groups(self.spec, counters)
        except InputError as error:
            return None, str(error), []
        return groups, None, notes

    def has_run(self, run_id: str) -> bool:
        """Whether the calibrator holds a row of run ``run_id``."""
        if self.calibrator is None:
            return False
        prefix = f"{run_id}:"
        return any(str(o.name).startswith(prefix) for o in self.calibrator.observations)

    def _remember_candidate(self, record: RunRecord, obs: Any) -> None:
        """Keep the row of each kind of run (kernel × threads) as a candidate for :meth:`suggest`."""
        kernel = record.kernel
        key = "idle" if kernel in NO_TRAFFIC_KERNELS or not record.elements else f"{kernel}-{record.threads}t"
        self._candidates[key] = obs
        while len(self._candidates) > MAX_CANDIDATES:
            self._candidates.pop(next(iter(self._candidates)))

    def suggest(self, top: int = 3) -> list[list[Any]] | None:
        """The best next runs among those seen (``[[name, score], ...]``, best first), or None."""
        if self.calibrator is None or self.calibrator.latest is None or not self._candidates:
            return None
        from hdeem_watch.calibrate import suggest_next

        try:
            ranking = suggest_next(self.calibrator, self._candidates)
        except (InputError, ValueError, np.linalg.LinAlgError):
            return None
        return [[name, round(float(score), 4)] for name, score in ranking[:top]]

    def reset(self, group: str | None = None) -> None:
        """Forget the runs and fits of ``group`` (a sensor group, ``"node"``: the node fit, or
        ``"total"``: the fit of the groups' sum); None: every run and fit.

        Raises:
            InputError: an unknown group.
        """
        if group == "node":  # the node fit (what ``calib show`` shows as node)
            if self.calibrator is not None:
                self.calibrator.reset()
            self.history.clear()
            return
        if group is not None:
            if self.group_fits is None:
                raise InputError(f"calib.reset: group {group!r}: the model is not available")
            self.group_fits.reset("node" if group == "total" else group)
            return
        if self.calibrator is not None:
            self.calibrator.reset()
        if self.group_fits is not None:
            self.group_fits.reset()
        self.history.clear()

    def take_alarms(self) -> list[DriftAlarm]:
        """The drift alarms the groups raised since the last call."""
        return [] if self.group_fits is None else self.group_fits.take_alarms()

    def state(self) -> dict[str, Any] | None:
        """The persistent state (None when there is no calibrator): the node calibrator's, with the
        groups' under ``sensor_groups``."""
        if self.calibrator is None:
            return None
        state = dict(self.calibrator.to_dict())
        groups = None if self.group_fits is None else self.group_fits.state()
        if groups is not None:
            state["sensor_groups"] = groups
        return state

    def body(self, truth: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """The ``calib`` topic body (``truth`` only from a simulated source)."""
        drift = {}
        if self.calibrator is not None:
            try:
                drift = dict(self.calibrator.drift())
            except Exception:
                drift = {}
        return {
            "fit": self.latest_fit(),
            "history": list(self.history),
            "runs": 0 if self.calibrator is None else len(self.calibrator.observations),
            "drift": drift,
            "memspec": self.memspec,
            "model_error": self.error,
            "truth": dict(truth) if truth is not None else None,
            "suggest": self.suggest(),
            "node_skipped": list(self.skipped[-20:]),
            **(self.group_fits.body() if self.group_fits is not None else {}),
        }
