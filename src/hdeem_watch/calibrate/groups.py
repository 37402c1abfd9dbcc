"""Per-sensor-group calibration: one online fit per sensor group (each HDEEM DIMM pair, each RAPL
socket) beside the node-level fit, with guard rails, drift detection and a sibling comparison.

The groups and their rows are :mod:`hdeem_watch.calibrate.group_rows` (re-exported here): a
group's row is each socket's one-channel row times the group's DIMMs on it, against the group's own
measured energy. The node-level row is the sum of the groups' rows against the sum of their
energies.

Guard rails: a run with fewer than ``min_samples`` sensor samples in a group's window (default 100:
1 s at HDEEM's 100 Sa/s) or without a measured energy is recorded in :attr:`GroupCalibrators.skipped`
with the reason and not fitted (a 10 ms run is one sample: it measures nothing). A group
fit whose currents hit a bound has status ``at-bound`` (:func:`~hdeem_watch.calibrate.fit.fit`).

Aging: per group a :class:`~hdeem_watch.calibrate.drift.ResidualCusum` on the change of its
residual since its previous run of the same kind (against the siblings' median change), and after
each refit :func:`~hdeem_watch.calibrate.drift.sibling_changes`: each group's identifiable currents
against its own reference fit, relative to its siblings' (drift.py states the statistics).

Pure: no clock, no I/O; the daemon persists :meth:`GroupCalibrators.to_dict` and serves
:meth:`GroupCalibrators.body` as ``calib.get``'s ``groups``/``node`` (docs/calibration.md).

Example::

    groups = sensor_groups(sensor_map(node), {d.locator: d.socket for d in node.dimms}, sockets=2)
    calib = GroupCalibrators(spec, groups)
    update = calib.add_run(MeasuredRun("triad", t_ns, 2.0, node_run_stats(spec, "triad", n, 24, 1),
                                       {"DDR_AB": 9.1, "DDR_CD": 9.3, ...}))
    update.skipped, update.alarms, calib.body()["groups"]["DDR_AB"]["fit"]["currents"]
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hdeem_watch.calibrate.drift import (
    DriftAlarm,
    ResidualCusum,
    identifiable_currents,
    sibling_changes,
    sibling_residuals,
)
from hdeem_watch.calibrate.group_rows import (
    DEFAULT_MIN_SAMPLES,
    MeasuredRun,
    SensorGroup,
    group_observation,
    measured_run,
    sensor_groups,
    summed,
    unmeasured_reason,
)
from hdeem_watch.calibrate.observation import Observation
from hdeem_watch.calibrate.online import OnlineCalibrator
from hdeem_watch.calibrate.result import FitResult
from hdeem_watch.dram.memspec import MemSpec
from hdeem_watch.errors import InputError

__all__ = ["DEFAULT_MIN_SAMPLES", "NODE", "TOTAL", "GroupCalibrators", "GroupUpdate", "MeasuredRun", "SensorGroup",
           "SkippedRun", "group_observation", "measured_run", "sensor_groups", "unmeasured_reason"]

#: The node-level fit's name beside the groups (in alarms, ``reset``, ``calib show --group``).
NODE = "node"
#: The key of the node-level fit in :meth:`GroupCalibrators.body` (a stream message's header
#: already has a ``node``: the node's name).
TOTAL = "total"
#: Skipped runs and alarms kept (oldest dropped first).
MAX_RECORDS = 200
#: Kinds of run whose latest rows each group keeps for the drift detector (oldest dropped first).
MAX_KINDS = 64
#: Runs of one kind a new run is compared with (their mean log residual): with ``L`` of them the
#: change's variance is ``σ²(1 + 1/L)`` instead of ``2σ²``, and a steady drift shows ``(L + 1)/2``
#: recurrences' worth of it instead of one.
KIND_REFERENCES = 3
_STATE_VERSION = 2


@dataclass(frozen=True)
class SkippedRun:
    """A run (or one group's part of it) recorded but not fitted, and why."""

    name: str
    time_ns: int
    group: str
    reason: str

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {"name": self.name, "time_ns": int(self.time_ns), "group": self.group, "reason": self.reason}


@dataclass(frozen=True)
class GroupUpdate:
    """What one run changed: the refits (group or :data:`NODE` → fit), what was skipped, new alarms."""

    fits: dict[str, FitResult] = field(default_factory=dict)
    skipped: tuple[SkippedRun, ...] = ()
    alarms: tuple[DriftAlarm, ...] = ()


class GroupCalibrators:
    """One :class:`~hdeem_watch.calibrate.online.OnlineCalibrator` per sensor group plus the node's.

    Args:
        spec: the memspec of one DIMM.
        groups: the sensor groups (:func:`sensor_groups`).
        min_samples: fewest samples per sensor for a run to be fitted.
        nominal_rate_hz: samples per second assumed when a run does not say how many it had.
        calibrator: keyword arguments of every :class:`OnlineCalibrator` (currents, half_life_s, ...).
        cusum: keyword arguments of every :class:`~hdeem_watch.calibrate.drift.ResidualCusum`.
        detect_after: a group's same-kind changes feed its detector, and its currents the sibling
            comparison, once its fit has this many runs (default: four times the unknowns — an
            earlier fit splits a run's energy between its length and its traffic too loosely for
            two runs of one kind but other lengths to compare).
        sibling_tolerance: see :func:`~hdeem_watch.calibrate.drift.sibling_changes`.
        node_detector: run a residual CUSUM on the node fit too. Off by default: the node has no
            siblings to difference against, so what the model leaves out stays in its residuals
            (it raised most false alarms in the benchmark); the groups' detectors name the pair.
    """

    def __init__(self, spec: MemSpec, groups: Sequence[SensorGroup], *, min_samples: int = DEFAULT_MIN_SAMPLES,
                 nominal_rate_hz: float = 100.0, calibrator: Mapping[str, Any] | None = None,
                 cusum: Mapping[str, Any] | None = None, detect_after: int | None = None,
                 sibling_tolerance: float = 0.15, node_detector: bool = False) -> None:
        if not groups:
            raise InputError("groups: no sensor groups to calibrate")
        names = [g.name for g in groups]
        if len(set(names)) != len(names) or NODE in names:
            raise InputError(f"groups: names must be unique and not {NODE!r}: {names}")
        if isinstance(min_samples, bool) or not isinstance(min_samples, int) or min_samples < 1:
            raise InputError(f"min_samples: {min_samples!r}; expected an integer >= 1")
        self.spec = spec
        self.groups = {g.name: g for g in groups}
        self.min_samples = min_samples
        self.nominal_rate_hz = float(nominal_rate_hz)
        self.calibrator_options = dict(calibrator or {})
        self.cusum_options = dict(cusum or {})
        self.sibling_tolerance = float(sibling_tolerance)
        self.node_detector = bool(node_detector)
        self.calibrators = {name: OnlineCalibrator(spec, **self.calibrator_options) for name in [*names, NODE]}
        unknowns = len(self.calibrators[NODE].currents) + int(self.calibrators[NODE].intercept)
        self.detect_after = 4 * unknowns if detect_after is None else int(detect_after)
        self.detectors = {name: ResidualCusum(name, **self.cusum_options) for name in [*names, NODE]}
        self.skipped: list[SkippedRun] = []
        self.alarms: list[DriftAlarm] = []
        self._raised: set[tuple[str, str, str]] = set()
        #: group → kind → the latest rows of that kind (the drift detector's reference runs).
        self.last_of_kind: dict[str, dict[str, list[Observation]]] = {name: {} for name in self.calibrators}
        #: group → its reference currents for the sibling comparison.
        self.reference: dict[str, dict[str, tuple[float, float, float]]] = {}

    def _samples(self, run: MeasuredRun, sensor: str) -> int:
        if run.samples is not None and sensor in run.samples:
            return int(run.samples[sensor])
        return math.floor(run.window_s * self.nominal_rate_hz + 1e-9)

    def _why_not(self, run: MeasuredRun, group: SensorGroup) -> str | None:
        return unmeasured_reason(run.name, group.name, run.energy_j.get(group.name), self._samples(run, group.name),
                                 run.window_s, self.min_samples)

    def predicted_j(self, group: str, obs: Observation) -> float:
        """``obs`` predicted by ``group``'s latest fit (NaN without one)."""
        calib = self.calibrators[group]
        fit = calib.latest
        if fit is None:
            return math.nan
        values = dict(self.spec.currents)
        values.update(fit.calibrated)
        vec = np.array([values.get(n, 0.0) for n in calib.names])
        return obs.predicted_j(vec, fit.intercept_j)

    def add_run(self, run: MeasuredRun) -> GroupUpdate:
        """Fit the run into every group it measured enough of (and the node if all of them), feed
        the detectors, compare siblings.

        Raises:
            InputError: the model's statistics do not fit the memspec (a bad row).
        """
        skipped: list[SkippedRun] = []
        rows: dict[str, Observation] = {}
        for name, group in self.groups.items():
            reason = self._why_not(run, group)
            if reason is not None:
                skipped.append(SkippedRun(run.name, run.time_ns, name, reason))
                continue
            rows[name] = group_observation(self.spec, run.socket_stats, group, run.window_s,
                                           float(run.energy_j[name]), name=run.name, time_ns=run.time_ns,
                                           traffic_s=run.traffic_s)
        if len(rows) == len(self.groups):
            rows[NODE] = summed(list(rows.values()), sum(r.measured_j for r in rows.values()))
        else:
            skipped.append(SkippedRun(run.name, run.time_ns, NODE, "not every group was measured: "
                                      + "; ".join(s.reason for s in skipped)))
        changes = self._same_kind_changes(run.kind_key, rows)
        drifting = {g for g, d in self.detectors.items() if d.alarmed}
        against = sibling_residuals({g: r for g, r in changes.items() if g != NODE}, exclude=drifting)
        if self.node_detector and NODE in changes:
            against[NODE] = changes[NODE]
        raised = [a for g, d in against.items()
                  if (a := self.detectors[g].update(d * _noise_weight(rows[g]), run.time_ns)) is not None]
        alarms: list[DriftAlarm] = []
        if raised:
            # A drifting group pulls its siblings' median, so in the run it crosses the threshold a
            # sibling can cross too, the other way: the alarm goes to the largest CUSUM; every other
            # group's sums start again (what they took from the drifting reference goes), and a
            # second group that really drifts crosses again with the first one out of its median.
            winner = max(raised, key=lambda a: a.statistic)
            alarms.append(winner)
            crossed = {a.group for a in raised}
            for name, detector in self.detectors.items():
                if name == winner.group:
                    continue
                if name in crossed:
                    detector.alarmed = False
                if not detector.alarmed:
                    detector.restart()
        fits = {name: self.calibrators[name].add_run(obs) for name, obs in rows.items()}
        if fits:
            alarms += self._sibling_alarms(run.time_ns)
        self.skipped = (self.skipped + skipped)[-MAX_RECORDS:]
        self.alarms = (self.alarms + alarms)[-MAX_RECORDS:]
        return GroupUpdate(fits=fits, skipped=tuple(skipped), alarms=tuple(alarms))

    def _log_residual(self, name: str, obs: Observation) -> float:
        predicted = self.predicted_j(name, obs)
        return math.log(obs.measured_j / predicted) if predicted > 0 else math.nan

    def _same_kind_changes(self, kind: str, rows: Mapping[str, Observation]) -> dict[str, float]:
        """Each group's ``x = log(m/p) − mean log(m'/p')`` over its last :data:`KIND_REFERENCES` runs
        of ``kind`` (all with its current fit; drift.py), for groups whose fit has
        :attr:`detect_after` runs; remembers the rows as the kind's latest."""
        out = {}
        for name, obs in rows.items():
            calib = self.calibrators[name]
            kinds = self.last_of_kind[name]
            previous = kinds.pop(kind, [])
            if previous and calib.latest is not None and len(calib.observations) >= self.detect_after:
                x = self._log_residual(name, obs) - float(np.mean([self._log_residual(name, p) for p in previous]))
                if math.isfinite(x):
                    out[name] = x
            kinds[kind] = [*previous, obs][-KIND_REFERENCES:]
            while len(kinds) > MAX_KINDS:
                kinds.pop(next(iter(kinds)))
        return out

    def _sibling_alarms(self, time_ns: int) -> list[DriftAlarm]:
        """:func:`~hdeem_watch.calibrate.drift.sibling_changes` of the groups' latest fits against
        their references (a group's reference is its fit when it first had :attr:`detect_after` runs);
        each (group, current) alarms once."""
        now = {}
        for name, calib in self.calibrators.items():
            if name == NODE or calib.latest is None or len(calib.observations) < self.detect_after:
                continue
            now[name] = identifiable_currents(calib.latest)
            self.reference.setdefault(name, now[name])
        out = []
        for alarm in sibling_changes(now, self.reference, time_ns=time_ns, tolerance=self.sibling_tolerance):
            key = (alarm.group, alarm.current, alarm.kind)
            if key not in self._raised:
                self._raised.add(key)
                out.append(alarm)
        return out

    def reset(self, group: str | None = None) -> None:
        """Forget the runs, fits, detector state and alarms of ``group`` (None: every group and the node).

        Raises:
            InputError: an unknown group.
        """
        names = list(self.calibrators) if group is None else [group]
        for name in names:
            if name not in self.calibrators:
                raise InputError(f"calib reset: unknown group {name!r}; expected one of {', '.join(self.calibrators)}")
            self.calibrators[name].reset()
            self.detectors[name].reset()
            self.last_of_kind[name].clear()
            self.reference.pop(name, None)
        self.alarms = [a for a in self.alarms if a.group not in names]
        self.skipped = [s for s in self.skipped if s.group not in names]
        self._raised = {k for k in self._raised if k[0] not in names}

    def group_body(self, name: str) -> dict[str, Any]:
        """One entry of :meth:`body`'s ``groups`` (or its ``node``)."""
        calib = self.calibrators[name]
        history = [{"time_ns": int(t), "status": r.status, "error_loo": _num(r.error_loo),
                    "currents": {c: _num(v) for c, v in r.calibrated.items()}} for t, r in calib.history[-64:]]
        group = self.groups.get(name)
        return {
            "fit": None if calib.latest is None else calib.latest.to_dict(),
            "runs": len(calib.observations),
            "dimms_per_socket": list(group.dimms_per_socket) if group else None,
            "drift": calib.drift(),
            "detector": self.detectors[name].to_dict(),
            "alarms": [a.to_dict() for a in self.alarms if a.group == name],
            "history": history,
        }

    def body(self) -> dict[str, Any]:
        """The ``calib.get`` shape: ``{"groups": {name: entry}, "total": entry (the node-level fit of
        the groups' sum; not ``"node"``: the stream's header has that key), "alarms", "skipped",
        "min_samples"}`` (docs/calibration.md, "Per-sensor-group fits")."""
        return {
            "groups": {name: self.group_body(name) for name in self.groups},
            TOTAL: self.group_body(NODE),
            "alarms": [a.to_dict() for a in self.alarms],
            "skipped": [s.to_dict() for s in self.skipped],
            "min_samples": self.min_samples,
        }

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready state (each calibrator's own state, detectors, alarms, skipped runs)."""
        return {
            "version": _STATE_VERSION,
            "groups": {name: list(g.dimms_per_socket) for name, g in self.groups.items()},
            "min_samples": self.min_samples, "nominal_rate_hz": self.nominal_rate_hz,
            "detect_after": self.detect_after, "sibling_tolerance": self.sibling_tolerance,
            "node_detector": self.node_detector,
            "cusum": self.cusum_options,
            "calibrators": {name: c.to_dict() for name, c in self.calibrators.items()},
            "detectors": {name: d.to_dict() for name, d in self.detectors.items()},
            "alarms": [a.to_dict() for a in self.alarms],
            "skipped": [s.to_dict() for s in self.skipped],
            "last_of_kind": {name: {k: [o.to_dict() for o in rows] for k, rows in kinds.items()}
                             for name, kinds in self.last_of_kind.items()},
            "reference": {name: {c: list(v) for c, v in per.items()} for name, per in self.reference.items()},
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], spec: MemSpec) -> GroupCalibrators:
        """Restore from :meth:`to_dict`.

        Raises:
            InputError: an unknown version or a malformed state.
        """
        if not isinstance(data, Mapping) or data.get("version") not in (1, _STATE_VERSION):
            raise InputError("group calibrators state: unknown version; expected "
                             f"{_STATE_VERSION}")
        try:
            groups = [SensorGroup(n, tuple(int(k) for k in v)) for n, v in data["groups"].items()]
            out = cls(spec, groups, min_samples=int(data["min_samples"]),
                      nominal_rate_hz=float(data["nominal_rate_hz"]), cusum=data.get("cusum") or {},
                      detect_after=int(data["detect_after"]), sibling_tolerance=float(data["sibling_tolerance"]),
                      node_detector=bool(data.get("node_detector", False)))
            out.calibrators = {n: OnlineCalibrator.from_dict(s, spec) for n, s in data["calibrators"].items()}
            if data.get("version") == _STATE_VERSION:  # version 1 detectors judged other inputs: start afresh
                out.detectors = {n: ResidualCusum.from_dict(n, s) for n, s in data["detectors"].items()}
            out.alarms = [DriftAlarm(**a) for a in data.get("alarms", [])]
            out.skipped = [SkippedRun(**s) for s in data.get("skipped", [])]
            for name, kinds in (data.get("last_of_kind") or {}).items():
                if name in out.last_of_kind:
                    out.last_of_kind[name] = {str(k): [Observation.from_dict(o) for o in rows]
                                              for k, rows in kinds.items()}
            out.reference = {str(n): {str(c): (float(v[0]), float(v[1]), float(v[2])) for c, v in per.items()}
                             for n, per in (data.get("reference") or {}).items()}
        except (KeyError, TypeError, ValueError) as error:
            raise InputError(f"group calibrators state: malformed ({error!r})") from None
        out._raised = {(a.group, a.current, a.kind) for a in out.alarms if a.kind == "sibling"}
        return out


def _noise_weight(obs: Observation) -> float:
    """``√(P / 1 W)`` of the run's mean power ``P``: the same-kind change's noise falls about as
    ``1/√P`` (on the sim: ~0.3–0.7 % for a loaded pair at 2–3.5 W, 1.1–2.3 % idle at 0.3–0.7 W; × √P
    it varies by a factor of two across kinds instead of eight), so the detector standardises
    ``d·√P`` by one scale (1 without a window)."""
    window = obs.window_s
    if not (math.isfinite(window) and window > 0):
        return 1.0
    return math.sqrt(obs.measured_j / window)


def _num(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None
