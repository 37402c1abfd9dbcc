"""Counted fits per socket and the node figure they make (nodes with one DRAM sensor per socket).

RAPL measures DRAM per socket, and a socket's DIMMs are one part: their currents differ from the
other socket's by the parts' spread (±10 % on the simulated DDR5 node) and the sensors' gain and
offset. One fit of the node's total then averages the sockets by load — and the demo's runs load
them unevenly (threads fill socket 0 first: at up to 56 threads of the DDR5 node socket 1 idles).
The fit cannot put one socket's higher currents into one socket, so it puts them into the column
that grows with the thread count's mix: on the DDR5 demo node IDD0 and IDD4R traded by ±10–16 %
against the sockets' mean truth while each socket's own counted fit was within 2 % of its truth.

So where every sensor measures one whole socket (:func:`socket_sensors`) and a run's commands are
counted per channel (the counters' ``sensors`` say which sensor each channel feeds), each socket is
fitted on its own rows (its channels' counted commands against its own measured energy), and the
node's currents are their mean over the DIMMs (:func:`combine`): what one DIMM of the node draws on
average, the figure a node memspec exports and the simulated node's truth averages. A prediction
is the sum of the sockets' predictions, each with its own fit (:meth:`SocketFits.predicted_j`).
HDEEM's DIMM pairs (two per socket) stay in the node fit: their per-pair fits
(:mod:`hdeem_watch.calibrate.groups`) serve the drift detectors.

Pure: no clock, no I/O.

Example:
    >>> from hdeem_watch.calibrate.group_rows import SensorGroup
    >>> socket_sensors([SensorGroup("DRAM0", (8, 0)), SensorGroup("DRAM1", (0, 8))])
    {'DRAM0': 8, 'DRAM1': 8}
    >>> socket_sensors([SensorGroup("DDR_AB", (2, 0)), SensorGroup("DDR_CD", (2, 0))])
    {}
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from hdeem_watch.calibrate.counter_model import counter_groups
from hdeem_watch.calibrate.group_rows import SensorGroup
from hdeem_watch.calibrate.observation import Observation, current_names
from hdeem_watch.calibrate.online import OnlineCalibrator
from hdeem_watch.calibrate.result import FitResult
from hdeem_watch.calibrate.rows import node_observation
from hdeem_watch.errors import InputError

#: The ``trust`` key of a combined fit: per socket, what its own fit says of each current.
PER_SOCKET = "per_socket"


def socket_sensors(groups: Sequence[SensorGroup]) -> dict[str, int]:
    """``{sensor: DIMMs}`` when every sensor measures exactly one whole socket (at least two
    sockets, no socket shared between sensors), else ``{}``."""
    owner: dict[int, str] = {}
    out: dict[str, int] = {}
    for group in groups:
        sockets = [s for s, n in enumerate(group.dimms_per_socket) if n > 0]
        if len(sockets) != 1 or sockets[0] in owner:
            return {}
        owner[sockets[0]] = group.name
        out[group.name] = group.dimms
    return out if len(out) >= 2 else {}


def sensor_counters(counters: Mapping[str, Any], sensor: str) -> dict[str, Any]:
    """The counters record restricted to the channels that feed ``sensor``."""
    feeds = counters.get("sensors") or {}
    channels = {c: v for c, v in (counters.get("channels") or {}).items() if feeds.get(c) == sensor}
    return {**counters, "channels": channels}


def socket_rows(spec: Any, counters: Mapping[str, Any] | None, energy_j: Mapping[str, float], sensors: Sequence[str],
                window_s: float, *, name: str, time_ns: int) -> dict[str, Observation] | None:
    """One counted row per socket sensor (its channels' commands against its energy), or None when
    the run cannot give them all (no counters, a sensor without channels or energy)."""
    if not isinstance(counters, Mapping) or not isinstance(counters.get("sensors"), Mapping):
        return None
    rows = {}
    for sensor in sensors:
        energy = energy_j.get(sensor)
        part = sensor_counters(counters, sensor)
        if not part["channels"] or not isinstance(energy, int | float) or not math.isfinite(energy) or energy <= 0:
            return None
        try:
            groups, _notes = counter_groups(spec, part)
            rows[sensor] = node_observation(spec, groups, window_s, float(energy), name=name, time_ns=time_ns,
                                            commands="counters")
        except InputError:
            return None
    return rows


def combine(fits: Mapping[str, FitResult], dimms: Mapping[str, int], base: FitResult, *,
            max_rel_ci: float = 0.2) -> FitResult:
    """The node's currents from the sockets' fits: their mean over the DIMMs (pure).

    A current's interval adds the sockets' weighted half-widths (each side) in quadrature: the
    sockets' fits are independent (other sensors, other rows). It is determined when every socket
    determines it, or when no socket holds it (held, tied or unconfirmed) and that half-width is
    within ``max_rel_ci`` of its value (the fit's setting). A current left undetermined gets the
    plain sum of the weighted half-widths instead (its bounds are the fits' bounds, not noise that
    averages out). ``base`` (the node fit of the summed rows) gives everything else: residual
    errors, runs, observability. ``trust.per_socket`` lists each socket's value and verdict.
    """
    total = float(sum(dimms[s] for s in fits))
    weights = {s: dimms[s] / total for s in fits}
    value = np.zeros(len(base.currents))
    spread = np.zeros((len(base.currents), 2))  # squared weighted distances to each socket's low and high bound
    linear = np.zeros((len(base.currents), 2))  # the same distances, summed
    determined = []
    per_socket: dict[str, dict[str, Any]] = {}
    for j, current in enumerate(base.currents):
        every, held = True, False
        for sensor, result in fits.items():
            k = result.currents.index(current)
            central = float(result.calibrated_a[k])
            value[j] += weights[sensor] * central
            low, high = np.nan_to_num(result.ci95_a[k], nan=central)
            distance = weights[sensor] * np.array([central - low, high - central])
            spread[j] += distance ** 2
            linear[j] += distance
            every &= bool(result.identifiable[k])
            trust = result.trust or {}
            held |= current in (trust.get("held") or {}) or current in (trust.get("unconfirmed") or ())
            per_socket.setdefault(sensor, {})[current] = {"calibrated": float(result.calibrated_a[k]),
                                                          "identifiable": bool(result.identifiable[k])}
        determined.append(every or (not held and float(np.sqrt(spread[j].max())) <= max_rel_ci * value[j]))
    half = np.where(np.array(determined)[:, None], np.sqrt(spread), linear)
    ci = np.column_stack([value - half[:, 0], value + half[:, 1]])
    trust = {**dict(base.trust or {}), PER_SOCKET: per_socket,
             "per_socket_note": "node currents = the sockets' counted fits averaged over the DIMMs"}
    intercept = float(sum(r.intercept_j for r in fits.values()))
    return dataclasses.replace(base, calibrated_a=value, ci95_a=ci, identifiable=np.array(determined),
                               intercept_j=intercept, trust=trust)


class SocketFits:
    """One counted calibrator per socket sensor; the node figure is their DIMM mean (module docstring).

    Args:
        spec: one DIMM's memspec.
        sensors: ``{sensor: DIMMs}`` (:func:`socket_sensors`).
        make: a new calibrator for one socket (the node calibrator's settings).
    """

    def __init__(self, spec: Any, sensors: Mapping[str, int], make: Callable[[], OnlineCalibrator]) -> None:
        self.spec = spec
        self.dimms = dict(sensors)
        self.calibrators = {s: make() for s in self.dimms}

    def add(self, rows: Mapping[str, Observation]) -> None:
        """Fit one run's rows, one per socket."""
        for sensor, row in rows.items():
            self.calibrators[sensor].add_run(row)

    def set_trust(self, trust: Any) -> None:
        """The trust options of every socket's refits (as the node calibrator's)."""
        for calibrator in self.calibrators.values():
            calibrator.trust = trust

    def refit(self) -> None:
        """Refit every socket (intervals in full)."""
        for calibrator in self.calibrators.values():
            calibrator.refit()

    def ready(self) -> bool:
        """Whether every socket has a fit."""
        return all(c.latest is not None for c in self.calibrators.values())

    def combined(self, base: FitResult | None) -> FitResult | None:
        """The node figure (:func:`combine`) over ``base``, or None until every socket has a fit."""
        if base is None or not self.ready():
            return None
        fits = {s: c.latest for s, c in self.calibrators.items() if c.latest is not None}
        rel = min(c.settings.max_rel_ci for c in self.calibrators.values())
        return combine(fits, self.dimms, base, max_rel_ci=rel)

    def predicted_j(self, rows: Mapping[str, Observation]) -> float | None:
        """The run's energy: each socket's row with its own latest fit, summed (None before every socket has one)."""
        if not self.ready() or set(rows) != set(self.calibrators):
            return None
        total = 0.0
        for sensor, row in rows.items():
            latest = self.calibrators[sensor].latest
            assert latest is not None
            total += row.predicted_j(_currents_vector(self.spec, latest), latest.intercept_j)
        return total

    def reset(self) -> None:
        """Forget every socket's runs."""
        for calibrator in self.calibrators.values():
            calibrator.reset()

    def to_dict(self) -> dict[str, Any]:
        """Persistent state: ``{"dimms", "calibrators": {sensor: OnlineCalibrator.to_dict()}}``."""
        return {"dimms": dict(self.dimms), "calibrators": {s: c.to_dict() for s, c in self.calibrators.items()}}

    def restore(self, state: Mapping[str, Any]) -> None:
        """Continue from a saved :meth:`to_dict` of the same sensors (anything else is ignored).

        Raises:
            InputError: a calibrator state this version cannot read.
        """
        saved = state.get("calibrators") or {}
        if set(saved) != set(self.calibrators):
            return
        for sensor, data in saved.items():
            restored = OnlineCalibrator.from_dict(data, self.spec)
            restored.trust = self.calibrators[sensor].trust
            self.calibrators[sensor] = restored


def _currents_vector(spec: Any, result: FitResult) -> np.ndarray:
    """The row's current vector (``current_names(spec)`` order): ``result``'s calibrated values, the
    datasheet's for the currents it does not calibrate."""
    values = {n: float(spec.currents.get(n, 0.0)) for n in current_names(spec)}
    for j, name in enumerate(result.currents):
        if name in values and math.isfinite(float(result.calibrated_a[j])):
            values[name] = float(result.calibrated_a[j])
    return np.array(list(values.values()))
