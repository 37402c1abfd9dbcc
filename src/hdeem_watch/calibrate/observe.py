"""What the runs determine, and which run to measure next.

The fit (:func:`~hdeem_watch.calibrate.fit.fit`) reports the observability of its prepared design
(singular values, condition number, column correlations, per-current sensitivity and the
identifiable flags). This module adds experiment design: :func:`suggest_next` ranks candidate runs
by how much adding each would shrink the posterior variance of the weakest current (the one with
the largest variance relative to its datasheet value), by a Sherman–Morrison update of the fit's
information matrix — the D-/A-optimal-design idea restricted to the parameter that matters.

Example (on precomputed columns; CommandStats candidates go through the energy model)::

    ranking = suggest_next(result, {"read": read_stats, "copy": copy_stats, "idle": idle_stats})
    best_name, score = ranking[0]   # score = fraction of the weakest current's variance removed
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from hdeem_watch.calibrate import solve
from hdeem_watch.calibrate.observation import Observation
from hdeem_watch.calibrate.online import OnlineCalibrator
from hdeem_watch.calibrate.result import FitModel, FitResult
from hdeem_watch.calibrate.rows import model_columns
from hdeem_watch.dram.memspec import MemSpec
from hdeem_watch.dram.stats import CommandStats
from hdeem_watch.errors import InputError


def _result_of(fit_or_calibrator: FitResult | OnlineCalibrator) -> FitResult:
    result = fit_or_calibrator.latest if isinstance(fit_or_calibrator, OnlineCalibrator) else fit_or_calibrator
    if not isinstance(result, FitResult):
        raise InputError("suggest_next: no fit yet (add runs first)")
    return result


def _model_of(result: FitResult) -> FitModel:
    if result.model is None:
        raise InputError("suggest_next: this fit was restored from a record and has no design; refit first")
    return result.model


def posterior_relative_sd(fit_or_calibrator: FitResult | OnlineCalibrator) -> dict[str, float]:
    """Per calibrated current, the posterior standard deviation per unit relative noise, as a
    fraction of its scale (datasheet value): large = weakly determined."""
    result = _result_of(fit_or_calibrator)
    model = _model_of(result)
    var = np.diag(np.linalg.inv(model.info))[: len(result.currents)]
    return {name: float(np.sqrt(v)) for name, v in zip(result.currents, var)}


def weakest_current(fit_or_calibrator: FitResult | OnlineCalibrator) -> str:
    """The calibrated current with the largest relative posterior variance."""
    sd = posterior_relative_sd(fit_or_calibrator)
    return max(sd, key=lambda name: sd[name])


def candidate_row(result: FitResult, candidate: CommandStats | Observation) -> np.ndarray:
    """The prepared design row a candidate run would add (relative to its predicted energy).

    Args:
        result: a fit with its model.
        candidate: command statistics (their own window; through the energy model) or an
            :class:`Observation` (its columns and constant; its measured energy is ignored).
    """
    model = _model_of(result)
    if isinstance(candidate, Observation):
        cols, const = candidate.columns, candidate.constant_j
    elif isinstance(model.spec, MemSpec):
        cols, const = model_columns(model.spec, candidate)
    else:
        raise InputError("suggest_next: command-statistics candidates need a fit on a full memspec "
                         "(this one has only currents); give Observations instead")
    all_a = np.array([float(model.spec.currents.get(nm, 0.0)) for nm in model.names])
    fixed = np.ones(len(model.names), dtype=bool)
    fixed[model.index] = False
    k = model.index.size
    x_a = cols[model.index]
    intercept = model.params[k] if model.params.size > k else 0.0
    predicted = float(x_a @ model.params[:k] + const + cols[fixed] @ all_a[fixed] + intercept)
    if not predicted > 0:
        raise InputError("suggest_next: a candidate predicts no energy (empty statistics?)")
    row = x_a * model.scales_a
    if model.params.size > k:
        row = np.append(row, model.intercept_scale_j)
    return row / predicted


def suggest_next(fit_or_calibrator: FitResult | OnlineCalibrator, candidates: Mapping[str, CommandStats | Observation], *,
                 target: str | None = None) -> list[tuple[str, float]]:
    """Rank candidate runs by how much each shrinks the variance of the weakest current.

    Args:
        fit_or_calibrator: a :class:`FitResult` or an
            :class:`~hdeem_watch.calibrate.online.OnlineCalibrator` (its latest fit).
        candidates: name → :class:`~hdeem_watch.dram.stats.CommandStats` (or an Observation).
        target: the current to determine (default: :func:`weakest_current`).

    Returns:
        ``[(name, score), ...]`` best first; score in [0, 1] is the fraction of the target's
        variance one such run would remove.

    Raises:
        InputError: no fit yet, an unknown target, or no candidates.
    """
    result = _result_of(fit_or_calibrator)
    model = _model_of(result)
    if not candidates:
        raise InputError("suggest_next: no candidate runs")
    target = target or weakest_current(result)
    if target not in result.currents:
        raise InputError(f"suggest_next: target {target!r} is not calibrated ({', '.join(result.currents)})")
    names = list(candidates)
    rows = np.array([candidate_row(result, candidates[name]) for name in names])
    scores = solve.variance_reduction(model.info, rows, result.currents.index(target))
    order = np.argsort(-scores, kind="stable")
    return [(names[i], float(scores[i])) for i in order]
