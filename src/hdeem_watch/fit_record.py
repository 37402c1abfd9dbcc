"""One calibration fit as it travels, and the one parser of its JSON form.

The calibrator's fit (``FitResult.to_dict()``, DESIGN.md §7) is sent as the ``calib`` topic's
``fit`` (and each sensor group's ``groups.<pair>.fit``, the node-level ``total.fit``), returned by
``calib.get``, carried in a run record's ``fit`` (the fit after the run), reduced to
``{"n_runs", "error": {"after"}}`` in a ``runs.list`` summary, and stored in the ``fits`` table.
The TUI, the report and the daemon's start-up checks read every one of these forms through
:meth:`FitRecord.from_dict`; nobody else parses a fit's JSON.

The parser is tolerant: a field that is missing or of the wrong type becomes unknown (NaN for
numbers, None for counts, verdicts and texts, never 0 or False) and is named in
:attr:`FitRecord.problems`. A record remembers the keys it was read with, in their order, and keeps
those it does not know (:attr:`FitRecord.extra`), so :meth:`FitRecord.to_dict` writes back the same
JSON, byte for byte, as the daemon wrote it — the full fit and the summary alike.

Example:
    >>> fit = FitRecord.from_dict({"currents": {"idd3n": {"datasheet": 0.05, "calibrated": 0.04,
    ...                            "ci95": [0.03, 0.05], "identifiable": True}}, "n_runs": 9,
    ...                            "error": {"after": 0.02}, "trust": {"commands": "counted", "held": {}}})
    >>> cur = fit.currents["idd3n"]
    >>> cur.calibrated_a, round(cur.half_width_a, 3), cur.verdict, fit.commands, fit.n_runs
    (0.04, 0.01, 'determined', 'counted', 9)
    >>> math.isnan(fit.error.before), fit.problems
    (True, ())
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

from hdeem_watch.record_fields import FieldReader, is_number

#: A fit's keys, in the order the calibrator writes them (``FitResult.to_dict``).
FIT_FIELDS = ("currents", "intercept_j", "intercept_ci95_j", "intercept_fitted", "error", "observability",
              "n_runs", "dof", "noise_rel", "status", "rules_held", "uncertainty", "time_ns", "runs", "trust")
#: The keys of one current's entry.
CURRENT_FIELDS = ("datasheet", "calibrated", "ci95", "identifiable", "at_bound", "sensitivity")
#: The keys of the fit's ``error`` (mean |relative error| before, after, leave-one-out).
ERROR_FIELDS = ("before", "after", "loo")
#: Fields every form of a fit has (a summary too); another one missing is not a problem.
_REQUIRED = ("n_runs", "error")

#: Where the fitted runs' command counts came from (``trust.commands``; ``commands_of``).
CommandSource = Literal["counted", "modelled", "mixed", "unknown"]
COMMAND_SOURCES: tuple[CommandSource, ...] = ("counted", "modelled", "mixed", "unknown")
#: A current's verdict: the runs determine it, it is held at a value the fit cannot see
#: (``trust.held``), or neither; ``unknown`` when the record does not say.
Verdict = Literal["determined", "held", "undetermined", "unknown"]


@dataclass(frozen=True, slots=True)
class CurrentFit:
    """One calibrated current (A; NaN = unknown).

    Attributes:
        name: the current (``idd3n``, ...), lower case as the calibrator writes it.
        datasheet_a: the memspec's value.
        calibrated_a: the fit's value (a held current's held value).
        ci95_a: the 95 % interval ``(low, high)``.
        identifiable: whether the runs determine it (None: not said).
        held: whether it is held (``trust.held``) rather than fitted.
        at_bound: the bound it sits at (``"lower"``/``"upper"``), None when free.
        sensitivity: the RMS fraction of the runs' energies it carries.
    """

    name: str
    datasheet_a: float = math.nan
    calibrated_a: float = math.nan
    ci95_a: tuple[float, float] = (math.nan, math.nan)
    identifiable: bool | None = None
    held: bool = False
    at_bound: str | None = None
    sensitivity: float = math.nan
    #: The keys it was read with, in order (:meth:`to_dict` writes those).
    keys: tuple[str, ...] = field(default=CURRENT_FIELDS, compare=False, repr=False)
    #: Keys of the read form this version does not know, written back as they were.
    extra: Mapping[str, Any] = field(default_factory=dict, compare=False, repr=False)

    @property
    def half_width_a(self) -> float:
        """Half the 95 % interval (NaN when unknown)."""
        return (self.ci95_a[1] - self.ci95_a[0]) / 2.0

    @property
    def verdict(self) -> Verdict:
        """``held`` before ``determined``: a held current is never determined by the runs."""
        if self.held:
            return "held"
        if self.identifiable is None:
            return "unknown"
        return "determined" if self.identifiable else "undetermined"

    def to_dict(self) -> dict[str, Any]:
        """The entry as the calibrator writes it (NaN as null)."""
        known = {"datasheet": _out(self.datasheet_a), "calibrated": _out(self.calibrated_a),
                 "ci95": [_out(self.ci95_a[0]), _out(self.ci95_a[1])], "identifiable": self.identifiable,
                 "at_bound": self.at_bound, "sensitivity": _out(self.sensitivity)}
        return _ordered(self.keys, known, self.extra)


@dataclass(frozen=True, slots=True)
class HeldCurrent:
    """A current held at its datasheet value scaled like ``anchor`` (no run shows its state).

    Attributes:
        value_a: the held value (A; NaN = unknown).
        anchor: the current it is scaled like (None: not said).
        range_a: the plausible range carried into the other currents' intervals.
    """

    value_a: float = math.nan
    anchor: str | None = None
    range_a: tuple[float, float] = (math.nan, math.nan)

    @classmethod
    def from_dict(cls, data: Any) -> HeldCurrent:
        """An entry of ``trust.held`` (unreadable fields unknown; it is the calibrator's detail)."""
        if not isinstance(data, Mapping):
            return cls()
        reader = _Reader(data, prefix="trust.held.")
        return cls(value_a=reader.real("value"), anchor=reader.text("anchor"), range_a=reader.pair("range"))


@dataclass(frozen=True, slots=True)
class FitError:
    """The fit's mean |relative error| over its runs (fractions; NaN = unknown).

    Attributes:
        before: with the datasheet currents.
        after: with the fitted currents (in sample).
        loo: leave-one-out (out of sample).
    """

    before: float = math.nan
    after: float = math.nan
    loo: float = math.nan
    keys: tuple[str, ...] = field(default=ERROR_FIELDS, compare=False, repr=False)
    extra: Mapping[str, Any] = field(default_factory=dict, compare=False, repr=False)

    def to_dict(self) -> dict[str, Any]:
        """The ``error`` object (NaN as null)."""
        known = {"before": _out(self.before), "after": _out(self.after), "loo": _out(self.loo)}
        return _ordered(self.keys, known, self.extra)


@dataclass(frozen=True, slots=True)
class FitRecord:
    """One fit: its currents, intercept, errors and verdicts (see the module docstring).

    ``observability``, ``runs`` (per-run ``name``, ``measured_j``, ``before_j``, ``after_j``,
    ``loo_j``) and ``trust`` are kept as the calibrator wrote them; :attr:`commands` and each
    current's ``held`` are read from ``trust``.
    """

    currents: Mapping[str, CurrentFit] = field(default_factory=dict)
    intercept_j: float = math.nan
    intercept_ci95_j: tuple[float, float] = (math.nan, math.nan)
    intercept_fitted: bool | None = None
    error: FitError = field(default_factory=FitError)
    observability: Mapping[str, Any] | None = None
    n_runs: int | None = None
    dof: int | None = None
    noise_rel: float = math.nan
    status: str | None = None
    rules_held: tuple[str, ...] = ()
    uncertainty: str | None = None
    time_ns: int | None = None
    runs: tuple[Mapping[str, Any], ...] = ()
    trust: Mapping[str, Any] | None = None
    #: Fields :meth:`from_dict` could not read, one line each (not sent).
    problems: tuple[str, ...] = field(default=(), compare=False, repr=False)
    keys: tuple[str, ...] = field(default=FIT_FIELDS, compare=False, repr=False)
    extra: Mapping[str, Any] = field(default_factory=dict, compare=False, repr=False)

    @property
    def commands(self) -> CommandSource | None:
        """Where the runs' command counts came from (``trust.commands``), None when not said."""
        value = (self.trust or {}).get("commands")
        return value if value in COMMAND_SOURCES else None

    @property
    def held(self) -> dict[str, HeldCurrent]:
        """The currents held at a value the runs cannot see (``trust.held``), by name."""
        held = (self.trust or {}).get("held")
        return {str(name): HeldCurrent.from_dict(entry) for name, entry in held.items()} \
            if isinstance(held, Mapping) else {}

    @property
    def unconfirmed(self) -> tuple[str, ...]:
        """Currents that rest on modelled activations nothing confirms (``trust.unconfirmed``)."""
        names = (self.trust or {}).get("unconfirmed")
        return tuple(str(n) for n in names) if isinstance(names, list) else ()

    @property
    def per_socket(self) -> dict[str, dict[str, tuple[float, bool]]]:
        """Per socket sensor, each current's value in its own fit (A; NaN = unknown) and whether that
        fit determines it (``trust.per_socket``: a node with one DRAM sensor per socket, whose
        currents are the sockets' mean over the DIMMs); ``{}`` for any other fit."""
        table = (self.trust or {}).get("per_socket")
        if not isinstance(table, Mapping):
            return {}
        out: dict[str, dict[str, tuple[float, bool]]] = {}
        for sensor, currents in table.items():
            if not isinstance(currents, Mapping):
                continue
            out[str(sensor)] = {
                str(name): (float(entry["calibrated"]) if is_number(entry.get("calibrated")) else math.nan,
                            entry.get("identifiable") is True)
                for name, entry in currents.items() if isinstance(entry, Mapping)}
        return out

    @property
    def calibrated_a(self) -> dict[str, float]:
        """The calibrated value of every current (A; NaN = unknown)."""
        return {name: cur.calibrated_a for name, cur in self.currents.items()}

    @property
    def determined(self) -> bool:
        """Whether the fit has more runs than unknowns: positive ``dof``; without it, more runs
        than currents (+ the intercept when fitted)."""
        if self.dof is not None:
            return self.dof > 0
        unknowns = len(self.currents) + (1 if self.intercept_fitted else 0)
        return self.n_runs is not None and self.n_runs > unknowns

    def runs_by_name(self) -> dict[str, Mapping[str, Any]]:
        """The per-run entries by observation name."""
        return {str(run.get("name")): run for run in self.runs}

    def to_dict(self) -> dict[str, Any]:
        """The fit as the calibrator writes it: the keys it was read with, in their order."""
        known = {
            "currents": {name: cur.to_dict() for name, cur in self.currents.items()},
            "intercept_j": _out(self.intercept_j),
            "intercept_ci95_j": [_out(self.intercept_ci95_j[0]), _out(self.intercept_ci95_j[1])],
            "intercept_fitted": self.intercept_fitted, "error": self.error.to_dict(),
            "observability": copy.deepcopy(self.observability), "n_runs": self.n_runs, "dof": self.dof,
            "noise_rel": _out(self.noise_rel), "status": self.status, "rules_held": list(self.rules_held),
            "uncertainty": self.uncertainty, "time_ns": self.time_ns,
            "runs": [copy.deepcopy(dict(run)) for run in self.runs], "trust": copy.deepcopy(self.trust),
        }
        return _ordered(self.keys, known, self.extra)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], *, strict: bool = False) -> FitRecord:
        """A record from any form of a fit (see the module docstring).

        Raises:
            ValueError: not a JSON object at all, or with ``strict`` any field unreadable or
                ``n_runs``/``error`` missing (the message names each).
        """
        if not isinstance(data, Mapping):
            raise ValueError(f"not a fit record: {type(data).__name__}")
        reader = _Reader(data)
        trust = reader.mapping("trust")
        held = trust.get("held") if trust is not None else None
        held_names = set(held) if isinstance(held, Mapping) else set()
        currents = {str(name): _current(reader, str(name), entry, str(name) in held_names)
                    for name, entry in (reader.mapping("currents") or {}).items()}
        runs = reader.array("runs") or []
        if not all(isinstance(run, Mapping) for run in runs):
            reader.problems.append("runs: expected a list of objects (the others left out)")
        record = cls(
            currents=currents, intercept_j=reader.real("intercept_j"),
            intercept_ci95_j=reader.pair("intercept_ci95_j"), intercept_fitted=reader.flag("intercept_fitted"),
            error=_error(reader), observability=reader.mapping("observability"), n_runs=reader.integer("n_runs"),
            dof=reader.integer("dof"), noise_rel=reader.real("noise_rel"), status=reader.text("status"),
            rules_held=tuple(str(r) for r in reader.array("rules_held") or ()), uncertainty=reader.text("uncertainty"),
            time_ns=reader.integer("time_ns"), runs=tuple(r for r in runs if isinstance(r, Mapping)), trust=trust,
            keys=tuple(data), extra={k: v for k, v in data.items() if k not in FIT_FIELDS},
            problems=tuple(reader.problems))  # last: after every field was read
        if strict and record.problems:
            raise ValueError("fit: " + "; ".join(record.problems))
        return record


def _current(reader: _Reader, name: str, entry: Any, held: bool) -> CurrentFit:
    """One entry of ``currents`` (problems named ``currents.<name>.<key>``)."""
    if not isinstance(entry, Mapping):
        reader.problems.append(f"currents.{name} = {str(entry)[:40]!r}: expected an object")
        return CurrentFit(name=name, held=held, keys=())
    sub = _Reader(entry, prefix=f"currents.{name}.", problems=reader.problems)
    return CurrentFit(name=name, datasheet_a=sub.real("datasheet"), calibrated_a=sub.real("calibrated"),
                      ci95_a=sub.pair("ci95"), identifiable=sub.flag("identifiable"), held=held,
                      at_bound=sub.text("at_bound"), sensitivity=sub.real("sensitivity"), keys=tuple(entry),
                      extra={k: v for k, v in entry.items() if k not in CURRENT_FIELDS})


def _error(reader: _Reader) -> FitError:
    """The ``error`` object (problems named ``error.<key>``)."""
    data = reader.mapping("error")
    if data is None:
        return FitError(keys=())
    sub = _Reader(data, prefix="error.", problems=reader.problems)
    return FitError(before=sub.real("before"), after=sub.real("after"), loo=sub.real("loo"), keys=tuple(data),
                    extra={k: v for k, v in data.items() if k not in ERROR_FIELDS})


class _Reader(FieldReader):
    """Reads a fit's fields (:class:`~hdeem_watch.record_fields.FieldReader`); an absent key is a
    problem only when :data:`_REQUIRED` (top level); null is unknown."""

    def __init__(self, data: Mapping[str, Any], *, prefix: str = "", problems: list[str] | None = None) -> None:
        super().__init__(data, required=() if prefix else _REQUIRED, prefix=prefix, problems=problems)

    def flag(self, key: str) -> bool | None:
        value = self.value(key, lambda v: isinstance(v, bool), "true or false")
        return None if value is None else bool(value)

    def pair(self, key: str) -> tuple[float, float]:
        value = self.value(key, lambda v: isinstance(v, list) and len(v) == 2 and
                           all(x is None or is_number(x) for x in v), "[low, high]")
        if value is None:
            return (math.nan, math.nan)
        return (math.nan if value[0] is None else float(value[0]), math.nan if value[1] is None else float(value[1]))


def _out(value: float) -> float | None:
    """A number as the calibrator writes it: non-finite as null."""
    return value if math.isfinite(value) else None


def _ordered(keys: tuple[str, ...], known: Mapping[str, Any], extra: Mapping[str, Any]) -> dict[str, Any]:
    """The keys in their read order: the known ones from the typed fields, the others as read."""
    return {key: known[key] if key in known else copy.deepcopy(extra[key]) for key in keys if key in known or key in extra}
