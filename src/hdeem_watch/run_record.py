"""One benchmark run as the daemon stores and sends it, and the one parser of its JSON form.

The daemon keeps a run as a :class:`RunRecord` from ``run.start`` to its model; the same record is
the ``run`` topic's body, a ``runs.list`` entry (a summary: the model and fit reduced to their
figures), a row of the state's ``runs`` table and what ``RunModeller.evaluate`` models. The TUI and
the report build their views from it; nobody else parses a run's JSON.

:meth:`RunRecord.from_dict` reads any stored or sent form, old ones included: a field that is
missing or of the wrong type becomes unknown (None, or NaN for a closed run's numbers, never 0) and
is named in :attr:`RunRecord.problems`; ``strict=True`` refuses such a record instead. Keys it does
not know are kept and written back by :meth:`RunRecord.to_dict`, so a record read and written again
is the same JSON, byte for byte, as the daemon wrote it.

Example:
    >>> rec = RunRecord.from_dict({"run_id": "r1", "state": "done", "kernel": "triad", "threads": 24,
    ...                            "dram_energy_j": None, "model": {"datasheet_j": 3.0}})
    >>> math.isnan(rec.dram_energy_j), rec.figures.datasheet_j, rec.problems[0]
    (True, 3.0, 'elements: missing')
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

RunState = Literal["running", "modelling", "done", "aborted"]
#: Every state of a run: ``running`` → ``modelling`` (the window closed) → ``done``, or ``aborted``.
RUN_STATES: tuple[RunState, ...] = ("running", "modelling", "done", "aborted")
FINISHED_STATES = ("done", "aborted")
#: Kernels that move no memory traffic: their run pins the standby currents and is an idle baseline.
NO_TRAFFIC_KERNELS = ("idle", "sleep")
#: The kernel of a run started without one (an opaque job): modelled from memory counters alone.
OPAQUE_KERNEL = "job"

#: The JSON keys of a record, in the order the daemon has always written them.
WIRE_FIELDS = ("run_id", "node", "name", "kernel", "threads", "elements", "repeat", "metadata", "t_start_ns",
               "state", "t_stop_ns", "window_s", "energy_j", "mean_power_w", "dram_energy_j", "model",
               "model_error", "fit", "samples_ns", "counters")


@dataclass(frozen=True)
class ModelFigures:
    """A run's modelled DRAM energies (node totals in J; NaN = not modelled or not known).

    Attributes:
        datasheet_j: the model with the datasheet currents.
        predicted_j: with the fit from before the run (out of sample).
        calibrated_j: the run's calibrated value (= ``predicted_j``).
        fitted_j: with the fit after the run was added.
    """

    datasheet_j: float = math.nan
    predicted_j: float = math.nan
    calibrated_j: float = math.nan
    fitted_j: float = math.nan


@dataclass
class RunRecord:
    """One run, from ``run.start`` to its model (see :data:`RUN_STATES`).

    Energies are per channel in J (NaN = unknown); ``model`` and ``fit`` are the calibrator's JSON
    contracts (``RunModeller.evaluate``). ``threads``, ``elements``, ``repeat`` and ``t_start_ns``
    are None only in a record read with those fields unknown (see :attr:`problems`).
    """

    run_id: str
    node: str
    name: str
    kernel: str
    threads: int | None
    elements: int | None
    repeat: int | None
    metadata: dict[str, Any]
    t_start_ns: int | None
    state: RunState = "running"
    t_stop_ns: int | None = None
    window_s: float | None = None
    energy_j: dict[str, float] | None = None
    mean_power_w: dict[str, float] | None = None
    dram_energy_j: float | None = None
    model: dict[str, Any] | None = None
    model_error: str | None = None
    fit: dict[str, Any] | None = None
    #: Per channel ``[last sample time before the window, last sample time in it]``.
    samples_ns: dict[str, list[int | None]] | None = None
    #: The memory counters over the window (``hdeem_watch.daemon.counters.windows``), None without.
    counters: dict[str, Any] | None = None
    #: Fields :meth:`from_dict` could not read, one line each (not sent).
    problems: tuple[str, ...] = field(default=(), compare=False, repr=False)
    #: Keys of the read form this version does not know, written back as they were (not typed).
    extra: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)

    @property
    def moves_no_traffic(self) -> bool:
        """Whether the run is an idle run (no memory traffic)."""
        return self.kernel in NO_TRAFFIC_KERNELS

    @property
    def figures(self) -> ModelFigures:
        """The model's energies (all NaN without a model)."""
        model = self.model or {}
        return ModelFigures(*(_number(model.get(key)) for key in
                              ("datasheet_j", "predicted_j", "calibrated_j", "fitted_j")))

    @property
    def simulated(self) -> bool:
        """Whether the run was announced as one on a simulated node (``metadata.simulated``)."""
        return bool(self.metadata.get("simulated", False))

    @property
    def holdout(self) -> bool:
        """Whether the run was announced as a hold-out (``metadata.holdout = true``): predicted, never fitted."""
        return self.metadata.get("holdout") is True

    @property
    def traffic_s(self) -> float | None:
        """How long the run's traffic lasted, as announced (``metadata.traffic_s``, else the demo
        schedule's ``metadata.modelled_s``); None when not announced or not a positive number."""
        for key in ("traffic_s", "modelled_s"):
            value = _number(self.metadata.get(key))
            if math.isfinite(value) and value > 0:
                return value
        return None

    def finish(self, *, energy_j: Mapping[str, float], window_s: float, dram_channels: Iterable[str],
               t_wall_ns: int, spans_s: Mapping[str, float] | None = None, aborted: bool = False) -> RunRecord:
        """A copy closed with its measured energies (``modelling``, or ``aborted``).

        ``spans_s`` gives each channel's own duration for its mean power (default ``window_s``).
        """
        spans = spans_s or {}
        power = {c: (e / spans.get(c, window_s) if spans.get(c, window_s) > 0 else math.nan)
                 for c, e in energy_j.items()}
        return dataclasses.replace(
            self, state="aborted" if aborted else "modelling", t_stop_ns=int(t_wall_ns), window_s=float(window_s),
            energy_j=dict(energy_j), mean_power_w=power, dram_energy_j=total_energy(energy_j, dram_channels))

    def to_dict(self) -> dict[str, Any]:
        """The JSON-ready record (NaN stays NaN; the protocol encoder sends null), the keys it was
        read with but does not know at the end."""
        out = {key: copy.deepcopy(getattr(self, key)) for key in WIRE_FIELDS}
        out.update(copy.deepcopy(self.extra))
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], *, strict: bool = False) -> RunRecord:
        """A record from any stored or sent form (see the module docstring).

        Raises:
            ValueError: not a run record at all (no string ``run_id``, no known ``state``), or with
                ``strict`` any field unreadable (the message names each).
        """
        if not isinstance(data, Mapping):
            raise ValueError(f"not a run record: {type(data).__name__}")
        run_id, state = data.get("run_id"), data.get("state")
        if not isinstance(run_id, str) or state not in RUN_STATES:
            raise ValueError(f"not a run record: run_id {run_id!r}, state {state!r}")
        reader = _Reader(data, closed=state != "running")
        kernel = reader.text("kernel", "?")
        record = cls(
            run_id=run_id, node=reader.text("node", "", required=False),
            name=reader.text("name", "", required=False) or kernel, kernel=kernel,
            threads=reader.integer("threads"), elements=reader.integer("elements"), repeat=reader.integer("repeat"),
            metadata=reader.mapping("metadata") or {}, t_start_ns=reader.integer("t_start_ns"), state=state,
            t_stop_ns=reader.integer("t_stop_ns", required=False), window_s=reader.real("window_s"),
            energy_j=reader.energies("energy_j"), mean_power_w=reader.energies("mean_power_w"),
            dram_energy_j=reader.real("dram_energy_j"), model=reader.mapping("model"),
            model_error=reader.text("model_error", None, required=False), fit=reader.mapping("fit"),
            samples_ns=reader.mapping("samples_ns"), counters=reader.mapping("counters"),
            problems=tuple(reader.problems), extra={k: v for k, v in data.items() if k not in WIRE_FIELDS})
        if strict and record.problems:
            raise ValueError(f"run {run_id}: " + "; ".join(record.problems))
        return record


class _Reader:
    """Reads the fields of one record, collecting what it could not read."""

    def __init__(self, data: Mapping[str, Any], *, closed: bool) -> None:
        self.data = data
        self.closed = closed  # a closed run's unknown numbers are NaN, a running one's None
        self.problems: list[str] = []

    def _bad(self, key: str, expected: str) -> None:
        if key not in self.data:
            self.problems.append(f"{key}: missing")
        else:
            self.problems.append(f"{key} = {str(self.data[key])[:40]!r}: expected {expected}")

    def text(self, key: str, default: Any, *, required: bool = True) -> Any:
        value = self.data.get(key)
        if isinstance(value, str):
            return value
        if required or value is not None:
            self._bad(key, "a string")
        return default

    def integer(self, key: str, *, required: bool = True) -> int | None:
        value = self.data.get(key)
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        if required or value is not None:
            self._bad(key, "an integer")
        return None

    def real(self, key: str) -> float | None:
        value = self.data.get(key)
        if isinstance(value, int | float) and not isinstance(value, bool):
            return float(value)
        if value is not None or (self.closed and key not in self.data):
            self._bad(key, "a number")
        return math.nan if self.closed else None

    def mapping(self, key: str) -> dict[str, Any] | None:
        value = self.data.get(key)
        if isinstance(value, Mapping):
            return dict(value)
        if value is not None:
            self._bad(key, "an object")
        return None

    def energies(self, key: str) -> dict[str, float] | None:
        values = self.mapping(key)
        if values is None:
            return None
        return {str(c): _number(v) for c, v in values.items()}


def _number(value: Any) -> float:
    """A JSON number as float; None and anything else NaN (unknown)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return math.nan
    return float(value)


def total_energy(energy_j: Mapping[str, float], channels: Iterable[str]) -> float:
    """Sum over ``channels`` (NaN when any of them is unknown or none is present).

    >>> total_energy({"DDR_AB": 1.0, "DDR_CD": 2.0}, ["DDR_AB", "DDR_CD"]), total_energy({}, ["DDR_AB"])
    (3.0, nan)
    """
    values = [energy_j.get(c, math.nan) for c in channels]
    if not values:
        return math.nan
    return float(sum(values))
