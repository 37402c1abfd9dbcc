"""Bounded linear least squares with its uncertainty: the pure numerical core of the calibrator.

Everything here works on a *prepared* design matrix ``D`` (rows already weighted, columns already
scaled so that each unknown is of order one) and a target ``t``: minimise ``½‖D·x − t‖²`` subject to
``lower ≤ x ≤ upper``, optionally plus a Gaussian prior ``½λ‖x − x0‖²``. A tiny ridge (``1e-12`` of
the largest squared singular value, toward ``x0``) is always added, so a rank-deficient system still
has one answer: directions the data do not determine stay at the prior target.

The solver is :func:`scipy.optimize.lsq_linear` (``trf``) on the ``p × p`` triangular factor of the
QR decomposition of ``D`` (same minimiser, so the cost of a solve does not grow with the rows).

Uncertainty (:func:`active_set_covariance`): the analytic covariance of the free parameters
``s²·(D_Fᵀ D_F + λI)⁻¹`` of the active set ``F`` (the bounds that hold are treated as known), with
``s² = RSS/(n − |F|)``; :func:`bootstrap` gives residual-bootstrap percentile intervals instead.
Leave-one-out (:func:`loo_residuals`): exact refits, or the hat-matrix identity
``e_i/(1 − h_ii)`` on the active set (exact as long as leaving one row out does not change which
bounds hold).

Example:
    >>> D = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    >>> sol = solve_bounded(D, np.array([0.5, 2.0, 1.5]), np.zeros(2), np.ones(2))
    >>> [round(float(v), 6) for v in sol.x], [int(a) for a in sol.active]
    ([0.5, 1.0], [0, 1])
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Relative size of the always-present ridge (times the largest squared singular value of ``D``).
RIDGE_RELATIVE = 1e-12


@dataclass(frozen=True)
class BoundedSolution:
    """Result of :func:`solve_bounded`.

    Attributes:
        x: the minimiser (scaled units).
        active: per parameter 0 = free, -1 = at its lower bound, +1 = at its upper bound.
        rss: residual sum of squares of the data rows (prior rows excluded).
        penalty: the prior + ridge strength that was applied (λ + ridge).
    """

    x: np.ndarray
    active: np.ndarray
    rss: float
    penalty: float


def ridge_strength(design: np.ndarray) -> float:
    """The always-present ridge for ``design``: ``RIDGE_RELATIVE·σ_max²`` (tiny, never 0)."""
    if design.size == 0:
        return RIDGE_RELATIVE
    top = float(np.linalg.norm(design, ord=2)) if design.shape[0] else 0.0
    return RIDGE_RELATIVE * max(top * top, 1e-300)


def solve_bounded(design: np.ndarray, target: np.ndarray, lower: np.ndarray, upper: np.ndarray, *,
                  prior_weight: np.ndarray | float = 0.0, prior_target: np.ndarray | None = None,
                  ridge: float | None = None) -> BoundedSolution:
    """Minimise ``½‖D·x − t‖² + ½Σ λ_j (x_j − x0_j)²`` within ``lower ≤ x ≤ upper``.

    Args:
        design: ``n × p`` prepared design matrix (may have fewer rows than columns).
        target: ``n`` prepared right-hand side.
        lower: ``p`` lower bounds (may be ``-inf``).
        upper: ``p`` upper bounds (may be ``inf``), each > its lower bound.
        prior_weight: λ per parameter (or one for all), ≥ 0.
        prior_target: x0 (default: zeros).
        ridge: the always-present ridge; default :func:`ridge_strength` of ``design``.

    Returns:
        The solution with its active set.
    """
    n, p = design.shape
    x0 = np.zeros(p) if prior_target is None else np.asarray(prior_target, dtype=float)
    ridge = ridge_strength(design) if ridge is None else ridge
    penalty = np.broadcast_to(np.asarray(prior_weight, dtype=float), (p,)) + ridge
    root = np.sqrt(penalty)
    stacked = np.vstack([design, np.diag(root)])
    rhs = np.concatenate([target, root * x0])
    q, r = np.linalg.qr(stacked, mode="reduced")
    reduced_rhs = q.T @ rhs
    # Start inside the box, at the prior target clipped to it (trf needs a strictly feasible start
    # only internally; it handles this itself).
    # scipy.optimize is imported here, on first use: importing it costs every process that merely
    # imports the calibrator (the daemon, each CLI command) ~0.3 s of start-up.
    from scipy.optimize import lsq_linear

    result = lsq_linear(r, reduced_rhs, bounds=(lower, upper), method="trf", lsq_solver="exact",
                        tol=1e-12, max_iter=200)
    x, active = _polish(r, reduced_rhs, lower, upper, np.clip(result.x, lower, upper),
                        np.asarray(result.active_mask, dtype=int))
    resid = design @ x - target if n else np.zeros(0)
    return BoundedSolution(x=x, active=active, rss=float(resid @ resid), penalty=float(penalty.max()))


def _polish(r: np.ndarray, rhs: np.ndarray, lower: np.ndarray, upper: np.ndarray, x: np.ndarray,
            mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Finish trf's interior-point answer exactly: take the bounds it (nearly) reached as active,
    solve the free parameters by least squares, and keep that if it is feasible and optimal (KKT:
    the gradient pushes every active parameter against its bound); else keep trf's answer."""
    span = np.where(np.isfinite(upper - lower), upper - lower, np.maximum(np.abs(x), 1.0))
    active = mask.copy()
    active[(x - lower) <= 1e-6 * span] = -1
    active[(upper - x) <= 1e-6 * span] = 1
    fixed = np.where(active == -1, lower, np.where(active == 1, upper, x))
    free = active == 0
    candidate = fixed.copy()
    if free.any():
        rest = rhs - r[:, ~free] @ fixed[~free]
        candidate[free] = np.linalg.lstsq(r[:, free], rest, rcond=None)[0]
    gradient = r.T @ (r @ candidate - rhs)
    scale = max(float(np.abs(r.T @ rhs).max(initial=0.0)), 1e-300)
    feasible = bool(np.all(candidate[free] >= lower[free]) and np.all(candidate[free] <= upper[free]))
    optimal = bool(np.all(gradient[active == -1] >= -1e-9 * scale)
                   and np.all(gradient[active == 1] <= 1e-9 * scale))
    if feasible and optimal:
        return candidate, active
    snapped = mask.copy()
    snapped[(x - lower) <= 1e-9 * span] = -1
    snapped[(upper - x) <= 1e-9 * span] = 1
    return np.where(snapped == -1, lower, np.where(snapped == 1, upper, x)), snapped


def information(design: np.ndarray, penalty: np.ndarray | float) -> np.ndarray:
    """``DᵀD + diag(penalty)`` (the Fisher information up to ``1/s²``)."""
    p = design.shape[1]
    return design.T @ design + np.diag(np.broadcast_to(np.asarray(penalty, dtype=float), (p,)))


def active_set_covariance(design: np.ndarray, free: np.ndarray, s2: float,
                          penalty: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Covariances of the parameters.

    Args:
        design: prepared ``n × p`` design.
        free: boolean mask of the parameters not at a bound.
        s2: residual variance (per prepared row).
        penalty: λ + ridge per parameter.

    Returns:
        ``(cov_active, cov_full)``: the active-set covariance (zero rows/columns for parameters at
        a bound) and the covariance ignoring the bounds (used for one-sided intervals at a bound
        and for identifiability).
    """
    p = design.shape[1]
    info = information(design, penalty)
    cov_full = s2 * np.linalg.inv(info)
    cov_active = np.zeros((p, p))
    idx = np.flatnonzero(free)
    if idx.size:
        cov_active[np.ix_(idx, idx)] = s2 * np.linalg.inv(info[np.ix_(idx, idx)])
    return cov_active, cov_full


def hat_diagonal(design: np.ndarray, free: np.ndarray, penalty: np.ndarray | float) -> np.ndarray:
    """Leverages ``h_ii`` of the rows on the free parameters (0 if none is free)."""
    idx = np.flatnonzero(free)
    if idx.size == 0:
        return np.zeros(design.shape[0])
    d_f = design[:, idx]
    info = information(design, penalty)[np.ix_(idx, idx)]
    return np.einsum("ij,ij->i", d_f @ np.linalg.inv(info), d_f)


def loo_residuals(design: np.ndarray, target: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                  solution: BoundedSolution, *, exact: bool, prior_weight: np.ndarray | float = 0.0,
                  prior_target: np.ndarray | None = None, ridge: float | None = None) -> np.ndarray:
    """Leave-one-out residuals in prepared units: row i predicted by the fit without row i.

    Args:
        design, target, lower, upper, prior_weight, prior_target, ridge: as for :func:`solve_bounded`.
        solution: the fit on all rows (used by the hat-matrix form).
        exact: refit without each row (``n`` solves) instead of the hat-matrix identity.
    """
    n = design.shape[0]
    if n < 2:
        return np.full(n, np.nan)
    ridge = ridge_strength(design) if ridge is None else ridge
    if not exact:
        resid = design @ solution.x - target
        lam = np.broadcast_to(np.asarray(prior_weight, dtype=float), (design.shape[1],)) + ridge
        h = hat_diagonal(design, solution.active == 0, lam)
        return resid / np.maximum(1.0 - h, 1e-12)
    out = np.empty(n)
    keep = np.ones(n, dtype=bool)
    for i in range(n):
        keep[i] = False
        sol = solve_bounded(design[keep], target[keep], lower, upper, prior_weight=prior_weight,
                            prior_target=prior_target, ridge=ridge)
        keep[i] = True
        out[i] = design[i] @ sol.x - target[i]
    return out


def bootstrap(design: np.ndarray, target: np.ndarray, lower: np.ndarray, upper: np.ndarray,
              solution: BoundedSolution, *, samples: int, seed: int, dof: int,
              prior_weight: np.ndarray | float = 0.0,
              prior_target: np.ndarray | None = None, ridge: float | None = None) -> np.ndarray:
    """Residual-bootstrap 95 % percentile intervals, ``p × 2`` (prepared units).

    The residuals of the fit are centred, inflated by ``sqrt(n/dof)`` and resampled with
    replacement onto the fitted values; each resample is solved within the bounds.
    """
    n, p = design.shape
    rng = np.random.default_rng(seed)
    fitted = design @ solution.x
    resid = target - fitted
    resid = (resid - resid.mean()) * np.sqrt(n / max(dof, 1))
    ridge = ridge_strength(design) if ridge is None else ridge
    draws = np.empty((samples, p))
    for k in range(samples):
        sample = fitted + resid[rng.integers(0, n, n)]
        draws[k] = solve_bounded(design, sample, lower, upper, prior_weight=prior_weight,
                                 prior_target=prior_target, ridge=ridge).x
    return np.percentile(draws, [2.5, 97.5], axis=0).T


def variance_reduction(info: np.ndarray, rows: np.ndarray, target_index: int) -> np.ndarray:
    """Fraction by which each candidate row would shrink the variance of one parameter.

    Adding row ``r`` to the information ``M`` gives (Sherman–Morrison)
    ``var' = var − (M⁻¹r)_j² / (1 + rᵀM⁻¹r)``; the score is ``1 − var'/var`` in ``[0, 1]``.

    Args:
        info: ``p × p`` information matrix (``DᵀD + penalty``).
        rows: ``c × p`` candidate rows, prepared like the design.
        target_index: the parameter whose variance matters.
    """
    inv = np.linalg.inv(info)
    var = inv[target_index, target_index]
    u = rows @ inv  # c × p  (M⁻¹ symmetric)
    quad = np.einsum("ij,ij->i", u, rows)
    gain = u[:, target_index] ** 2 / (1.0 + quad)
    return np.clip(gain / var, 0.0, 1.0)
