"""What a fit reports: :class:`FitResult` (its ``to_dict()`` is the JSON contract of DESIGN.md §7),
the :class:`FitSettings` that turn numbers into verdicts, and the :class:`FitModel` kept for
experiment design. Built by :func:`hdeem_watch.calibrate.fit.fit`.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hdeem_watch.calibrate.observation import SpecLike
from hdeem_watch.errors import InputError


@dataclass(frozen=True)
class FitSettings:
    """Thresholds that turn the fit's numbers into verdicts (all documented in docs/calibration.md).

    Attributes:
        noise_floor: relative noise assumed at least (the sensor's accuracy) when judging
            identifiability, so a noise-free synthetic fit does not call everything determined.
        max_rel_ci: a current is identifiable if its 95 % half-width (at ``max(s, noise_floor)``,
            bounds ignored) is at most this fraction of its calibrated value (at least 5 % of its
            datasheet value) ...
        min_sensitivity: ... and it carries at least this RMS fraction of the runs' energies.
        rank_tol: singular values below ``rank_tol·σ_max`` count as zero.
    """

    noise_floor: float = 0.01
    max_rel_ci: float = 0.2
    min_sensitivity: float = 0.002
    rank_tol: float = 1e-9

@dataclass(frozen=True, eq=False)
class FitResult:
    """A calibration: currents with 95 % intervals, what is determined, and errors.

    Arrays are over :attr:`currents`. Use :meth:`to_dict` for the JSON contract (DESIGN.md §7).
    Compared by identity (it holds arrays); compare ``to_dict()`` for equal content.

    Example::

        result = fit(rows, spec)
        result.calibrated["idd3n"]                      # amperes
        result.to_dict()["currents"]["idd3n"]["ci95"]   # [low, high] amperes
        spec.with_currents(result.calibrated)           # the calibrated memspec
    """

    currents: tuple[str, ...]
    datasheet_a: np.ndarray
    calibrated_a: np.ndarray
    ci95_a: np.ndarray
    identifiable: np.ndarray
    at_bound: tuple[str | None, ...]
    sensitivity: np.ndarray
    intercept_fitted: bool
    intercept_j: float
    intercept_ci95_j: tuple[float, float]
    error_before: float
    error_after: float
    error_loo: float
    singular_values: np.ndarray
    condition_number: float
    rank: int
    correlation: np.ndarray
    n_runs: int
    dof: int
    noise_rel: float
    status: str
    uncertainty: str
    runs: tuple[dict[str, Any], ...] = ()
    time_ns: int = 0
    #: The physical rules between calibrated currents that hold with equality (e.g. ``"ACT+PRE"``:
    #: IDD0 sits at the tRAS/tRC mix of IDD3N and IDD2N); see :mod:`hdeem_watch.calibrate.physical`.
    rules_held: tuple[str, ...] = ()
    #: What widened the intervals and which currents are held (:mod:`hdeem_watch.calibrate.trust`);
    #: None for a plain fit.
    trust: Mapping[str, Any] | None = None
    #: Everything :func:`~hdeem_watch.calibrate.observe.suggest_next` needs (absent after from_dict).
    model: FitModel | None = field(default=None, compare=False, repr=False)

    @property
    def calibrated(self) -> dict[str, float]:
        """Calibrated currents by name (A)."""
        return {n: float(v) for n, v in zip(self.currents, self.calibrated_a)}

    def interval(self, name: str) -> tuple[float, float]:
        """The 95 % interval of current ``name`` (A)."""
        j = self.currents.index(name)
        return float(self.ci95_a[j, 0]), float(self.ci95_a[j, 1])

    def determined(self, name: str) -> bool:
        """Whether the runs determine current ``name`` (its ``identifiable`` verdict)."""
        return bool(self.identifiable[self.currents.index(name)])

    def to_dict(self) -> dict[str, Any]:
        """The JSON contract: ``currents.<name>.{datasheet, calibrated, ci95, identifiable}``, ...

        Non-finite numbers are ``null`` (see ``status``).
        """
        currents = {}
        for j, name in enumerate(self.currents):
            currents[name] = {
                "datasheet": _num(self.datasheet_a[j]),
                "calibrated": _num(self.calibrated_a[j]),
                "ci95": [_num(self.ci95_a[j, 0]), _num(self.ci95_a[j, 1])],
                "identifiable": bool(self.identifiable[j]),
                "at_bound": self.at_bound[j],
                "sensitivity": _num(self.sensitivity[j]),
            }
        params = [*self.currents, *(["intercept"] if self.intercept_fitted else [])]
        return {
            "currents": currents,
            "intercept_j": _num(self.intercept_j),
            "intercept_ci95_j": [_num(self.intercept_ci95_j[0]), _num(self.intercept_ci95_j[1])],
            "intercept_fitted": self.intercept_fitted,
            "error": {"before": _num(self.error_before), "after": _num(self.error_after),
                      "loo": _num(self.error_loo)},
            "observability": {
                "condition_number": _num(self.condition_number),
                "singular_values": [_num(s) for s in self.singular_values],
                "rank": self.rank,
                "parameters": params,
                "rank_deficient": self.rank < len(params),
                "correlation": [[_num(c) for c in row] for row in self.correlation],
            },
            "n_runs": self.n_runs,
            "dof": self.dof,
            "noise_rel": _num(self.noise_rel),
            "status": self.status,
            "rules_held": list(self.rules_held),
            "uncertainty": self.uncertainty,
            "time_ns": self.time_ns,
            "runs": [dict(run) for run in self.runs],
            "trust": None if self.trust is None else dict(self.trust),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> FitResult:
        """Rebuild the reported part of a fit from :meth:`to_dict` (no ``model``).

        Raises:
            InputError: a missing or malformed field.
        """
        try:
            names = tuple(data["currents"])
            cur = data["currents"]
            obs = data["observability"]
            return cls(
                currents=names,
                datasheet_a=np.array([_flt(cur[n]["datasheet"]) for n in names]),
                calibrated_a=np.array([_flt(cur[n]["calibrated"]) for n in names]),
                ci95_a=np.array([[_flt(v) for v in cur[n]["ci95"]] for n in names]).reshape(len(names), 2),
                identifiable=np.array([bool(cur[n]["identifiable"]) for n in names]),
                at_bound=tuple(cur[n].get("at_bound") for n in names),
                sensitivity=np.array([_flt(cur[n].get("sensitivity")) for n in names]),
                intercept_fitted=bool(data.get("intercept_fitted", True)),
                intercept_j=_flt(data["intercept_j"]),
                intercept_ci95_j=tuple(_flt(v) for v in data.get("intercept_ci95_j", [None, None])),  # type: ignore[arg-type]
                error_before=_flt(data["error"]["before"]),
                error_after=_flt(data["error"]["after"]),
                error_loo=_flt(data["error"]["loo"]),
                singular_values=np.array([_flt(s) for s in obs["singular_values"]]),
                condition_number=_flt(obs["condition_number"]),
                rank=int(obs.get("rank", len(obs["singular_values"]))),
                correlation=np.array([[_flt(c) for c in row] for row in obs.get("correlation", [])]),
                n_runs=int(data.get("n_runs", 0)),
                dof=int(data.get("dof", 0)),
                noise_rel=_flt(data.get("noise_rel")),
                status=str(data.get("status", "ok")),
                uncertainty=str(data.get("uncertainty", "analytic")),
                runs=tuple(dict(r) for r in data.get("runs", [])),
                rules_held=tuple(str(r) for r in data.get("rules_held", [])),
                time_ns=int(data.get("time_ns", 0)),
                trust=dict(data["trust"]) if isinstance(data.get("trust"), Mapping) else None,
            )
        except (KeyError, TypeError, ValueError) as error:
            raise InputError(f"fit: malformed fit record ({error!r})") from None


#: Measured energies a median this many times the datasheet model's (or 1/this) mean wrong units.
IMPLAUSIBLE_ENERGY_RATIO = 20.0


def energy_units_warning(runs: Sequence[Mapping[str, Any]]) -> str | None:
    """A one-line warning when the measured energies cannot be in joules for this memspec, or None.

    ``runs`` are a fit's :attr:`FitResult.runs` (``measured_j`` and the datasheet model's
    ``before_j`` of each run).

    The datasheet model is rarely off by more than a factor of a few; a median ratio measured /
    datasheet-model energy beyond :data:`IMPLAUSIBLE_ENERGY_RATIO` (either way) means the energies
    are in other units (mJ: every current then pins at its upper bound) or ``scale`` is wrong —
    the fit still runs, but its currents mean nothing.

    Example:
        >>> runs = [{"measured_j": 1000.0 * e, "before_j": e} for e in (1.0, 2.0, 3.0)]
        >>> print(energy_units_warning(runs))
        measured energies are a median 1e+03x the datasheet model's: measured_j looks like mJ; expected joules
    """
    ratios = [run["measured_j"] / run["before_j"] for run in runs
              if run.get("before_j") and run["before_j"] > 0 and run.get("measured_j")]
    if not ratios:
        return None
    median = statistics.median(ratios)
    if median > IMPLAUSIBLE_ENERGY_RATIO:
        hint = ("measured_j looks like mJ; expected joules" if 200 <= median <= 5000 else
                "check that measured_j is in joules and that scale counts the channels it covers")
        return f"measured energies are a median {median:.3g}x the datasheet model's: {hint}"
    if median < 1 / IMPLAUSIBLE_ENERGY_RATIO:
        return (f"measured energies are a median 1/{1 / median:.3g} of the datasheet model's: check that "
                "measured_j is in joules (not kJ) and that scale and window_s are right")
    return None


@dataclass(frozen=True, eq=False)
class FitModel:
    """The prepared problem behind a fit, kept for experiment design (not serialised).

    Attributes:
        spec: the memspec the fit started from.
        names: the order of the observation columns.
        index: positions of the calibrated currents in ``names``.
        scales_a: column scale of each calibrated current (A; its datasheet value).
        intercept_scale_j: column scale of the intercept (J), 0 if not fitted.
        info: ``p × p`` information matrix of the prepared design (incl. penalty).
        params: the fitted parameters in amperes (then the intercept in J).
    """

    spec: SpecLike
    names: tuple[str, ...]
    index: np.ndarray
    scales_a: np.ndarray
    intercept_scale_j: float
    info: np.ndarray
    params: np.ndarray


def _num(value: Any) -> float | None:
    if value is None:
        return None
    v = float(value)
    return v if math.isfinite(v) else None


def _flt(value: Any) -> float:
    return math.nan if value is None else float(value)
