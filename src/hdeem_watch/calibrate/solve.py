"""Bounded linear least squares with its uncertainty: the pure numerical core of the calibrator.

Everything here works on a *prepared* design matrix ``D`` (rows already weighted, columns already
scaled so that each unknown is of order one) and a target ``t``: minimise ``½‖D·x − t‖²`` subject to
``lower ≤ x ≤ upper`` and optionally linear rules ``G·x ≥ h`` between the unknowns, optionally plus
a Gaussian prior ``½λ‖x − x0‖²``. A tiny ridge (``1e-12`` of the largest squared singular value,
toward ``x0``) is always added, so a rank-deficient system still has one answer: directions the
data do not determine stay at the prior target.

The solver works on the ``p × p`` triangular factor ``R`` of the QR decomposition of ``D`` (same
minimiser, so the cost of a solve does not grow with the rows): :func:`scipy.optimize.lsq_linear`
(``bvls``, Stark and Parker's active-set method: exact, and a few least-squares solves for the
handful of unknowns here; ``trf``'s interior-point iterations cost ~9× the CPU and stop short of
the bound on flat problems) for bounds alone; when that answer breaks a rule, Lawson and Hanson's reduction of least
squares under linear inequalities (LSI) to a least-distance problem (LDP), solved by
:func:`scipy.optimize.nnls` (Lawson & Hanson, *Solving Least Squares Problems*, 1974, ch. 23), and
finished by a primal active-set method (exact where ``R`` is ill conditioned).

Uncertainty (:func:`active_set_covariance`): the analytic covariance of the free parameters
``s²·(D_Fᵀ D_F + λI)⁻¹`` of the active set ``F`` (the bounds that hold are treated as known), with
``s² = RSS/(n − |F|)``; when rules hold, the covariance on the null space ``N`` of the constraints
that hold, ``s²·N(Nᵀ(DᵀD + λI)N)⁻¹Nᵀ``, and ``|F|`` its dimension. :func:`bootstrap` gives
residual-bootstrap percentile intervals instead.
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

from dataclasses import dataclass, field

import numpy as np

#: Relative slack within which a bound or rule counts as holding with equality.
_SLACK = 1e-9

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
        held: per rule row of ``G`` (see :func:`solve_bounded`), whether it holds with equality.
        held_rows: the rows of ``G`` that hold (``k × p``; empty without rules).
    """

    x: np.ndarray
    active: np.ndarray
    rss: float
    penalty: float
    held: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    held_rows: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    @property
    def free_dimension(self) -> int:
        """How many directions the constraints that hold leave free (``|F|`` without rules)."""
        if not self.held_rows.size:
            return int(np.count_nonzero(self.active == 0))
        return int(_free_basis(self.active, self.held_rows).shape[1])


def ridge_strength(design: np.ndarray) -> float:
    """The always-present ridge for ``design``: ``RIDGE_RELATIVE·σ_max²`` (tiny, never 0)."""
    if design.size == 0:
        return RIDGE_RELATIVE
    top = float(np.linalg.norm(design, ord=2)) if design.shape[0] else 0.0
    return RIDGE_RELATIVE * max(top * top, 1e-300)


def solve_bounded(design: np.ndarray, target: np.ndarray, lower: np.ndarray, upper: np.ndarray, *,
                  prior_weight: np.ndarray | float = 0.0, prior_target: np.ndarray | None = None,
                  ridge: float | None = None, rules: tuple[np.ndarray, np.ndarray] | None = None) -> BoundedSolution:
    """Minimise ``½‖D·x − t‖² + ½Σ λ_j (x_j − x0_j)²`` within ``lower ≤ x ≤ upper`` and ``G·x ≥ h``.

    Args:
        design: ``n × p`` prepared design matrix (may have fewer rows than columns).
        target: ``n`` prepared right-hand side.
        lower: ``p`` lower bounds (may be ``-inf``).
        upper: ``p`` upper bounds (may be ``inf``), each > its lower bound.
        prior_weight: λ per parameter (or one for all), ≥ 0.
        prior_target: x0 (default: zeros).
        ridge: the always-present ridge; default :func:`ridge_strength` of ``design``.
        rules: ``(G, h)``, ``k × p`` and ``k``: linear rules ``G·x ≥ h`` the solution keeps as well
            (None or ``k = 0``: bounds only). Rules the bounds make impossible are dropped: the
            solution then keeps the bounds alone and ``held`` is all False.

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
    # scipy.optimize is imported here, on first use: importing it costs every process that merely
    # imports the calibrator (the daemon, each CLI command) ~0.3 s of start-up.
    from scipy.optimize import lsq_linear

    result = lsq_linear(r, reduced_rhs, bounds=(lower, upper), method="bvls", tol=1e-12, max_iter=200)
    x, active = _polish(r, reduced_rhs, lower, upper, np.clip(result.x, lower, upper),
                        np.asarray(result.active_mask, dtype=int))
    held, held_rows = np.zeros(0, dtype=bool), np.zeros((0, p))
    if rules is not None and len(rules[1]):
        g, h = np.asarray(rules[0], dtype=float), np.asarray(rules[1], dtype=float)
        held = np.zeros(h.size, dtype=bool)
        if np.any(g @ x < h - _SLACK * np.maximum(1.0, np.abs(h))):  # the bounds alone break a rule
            constrained = _solve_with_rules(r, reduced_rhs, lower, upper, g, h)
            if constrained is not None:
                x, active, held = constrained
                held_rows = g[held] if held.any() else held_rows
    resid = design @ x - target if n else np.zeros(0)
    return BoundedSolution(x=x, active=active, rss=float(resid @ resid), penalty=float(penalty.max()),
                           held=held, held_rows=held_rows)


def _solve_with_rules(r: np.ndarray, rhs: np.ndarray, lower: np.ndarray, upper: np.ndarray, rules: np.ndarray,
                      floors: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """``min ‖R·x − c‖`` subject to ``A·x ≥ b`` (the rules and the finite bounds as rows), exactly.

    With ``z = R·x − c`` the problem becomes the least-distance problem ``min ‖z‖`` subject to
    ``Ĝ·z ≥ ĥ`` (``Ĝ = A·R⁻¹``, ``ĥ = b − Ĝ·c``; :func:`_least_distance`), which
    :func:`_active_set` then finishes exactly. ``R`` is square and non-singular here (the ridge
    rows are part of the factorised system).

    Returns:
        ``(x, active, held)`` (see :class:`BoundedSolution`), or None when the rows admit no ``x``.
    """
    p = r.shape[1]
    eye = np.eye(p)
    has_lower, has_upper = np.isfinite(lower), np.isfinite(upper)
    rows = np.vstack([rules, eye[has_lower], -eye[has_upper]])
    floors_all = np.concatenate([floors, lower[has_lower], -upper[has_upper]])
    norms = np.linalg.norm(rows, axis=1)
    norms = np.where(norms > 0, norms, 1.0)
    rows, floors_all = rows / norms[:, None], floors_all / norms
    r_inv = np.linalg.solve(r, eye)
    g_hat = rows @ r_inv
    z = _least_distance(g_hat, floors_all - g_hat @ rhs)
    if z is None:  # the rules and bounds admit no x
        return None
    x = r_inv @ (z + rhs)
    x = _active_set(r, rhs, rows, floors_all, x)
    tight = rows @ x - floors_all <= _SLACK * np.maximum(1.0, np.abs(floors_all))
    k = rules.shape[0]
    active = np.zeros(p, dtype=int)
    low_index, up_index = np.flatnonzero(has_lower), np.flatnonzero(has_upper)
    active[low_index[tight[k:k + low_index.size]]] = -1
    active[up_index[tight[k + low_index.size:]]] = 1
    x = np.where(active == -1, lower, np.where(active == 1, upper, np.clip(x, lower, upper)))
    return x, active, tight[:k].copy()


def _active_set(r: np.ndarray, rhs: np.ndarray, rows: np.ndarray, floors: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Finish the least-distance answer exactly, as :func:`_polish` does for bounds: a primal
    active-set method (Nocedal & Wright, *Numerical Optimization*, alg. 16.3) for
    ``min ‖R·x − c‖`` subject to ``rows·x ≥ floors``, started from ``x`` moved onto the feasible set.

    Each step solves the problem with the working set's rows as equalities (on their null space,
    which stays well conditioned where ``R⁻¹`` is not), walks towards that answer up to the first
    row it would break (which joins the set), and at a standstill drops the row whose multiplier
    pulls away from it (KKT: ``Rᵀ(R·x − c) = Aᵀ·μ`` with ``μ ≥ 0`` on the set). Returns ``x`` if
    no feasible point is found.
    """
    tolerance = _SLACK * np.maximum(1.0, np.abs(floors))
    point = _nearest_feasible(rows, floors, x)
    if point is None:
        return x
    scale = max(float(np.abs(r.T @ rhs).max(initial=0.0)), 1e-300)
    working: list[int] = []
    for index in np.flatnonzero(rows @ point - floors <= tolerance).tolist():
        if np.linalg.matrix_rank(rows[[*working, index]]) == len(working) + 1:
            working.append(index)
    for _ in range(20 * (rows.shape[0] + rows.shape[1])):
        target = _equality_solve(r, rhs, rows[working], floors[working])
        step = target - point
        if np.linalg.norm(step) <= 1e-12 * max(1.0, float(np.linalg.norm(point))):
            if not working:
                return point
            gradient = r.T @ (r @ point - rhs)
            multipliers = np.linalg.lstsq(rows[working].T, gradient, rcond=None)[0]
            if multipliers.min() >= -1e-9 * scale:
                return point
            del working[int(np.argmin(multipliers))]
            continue
        change = rows @ step
        room = rows @ point - floors
        blocking = [(max(float(room[i]), 0.0) / -float(change[i]), i) for i in range(rows.shape[0])
                    if i not in working and change[i] < 0 and max(float(room[i]), 0.0) < -change[i]]
        if blocking:
            alpha, first = min(blocking)
            point = point + alpha * step
            working.append(first)
        else:
            point = target
    return point


def _nearest_feasible(rows: np.ndarray, floors: np.ndarray, x: np.ndarray) -> np.ndarray | None:
    """The point nearest ``x`` with ``rows·y ≥ floors`` (a least-distance problem in the identity
    metric, well conditioned), or None when there is none."""
    shortfall = floors - rows @ x
    if np.all(shortfall <= 0):
        return x
    z = _least_distance(rows, shortfall)
    return None if z is None else x + z


def _least_distance(rows: np.ndarray, floors: np.ndarray) -> np.ndarray | None:
    """``min ‖z‖`` subject to ``rows·z ≥ floors`` (LDP), or None when no ``z`` keeps the rows: the
    answer is the residual ``ρ`` of the non-negative least squares ``min ‖[rowsᵀ; floorsᵀ]·u −
    e_{p+1}‖, u ≥ 0``, as ``z = −ρ[:p]/ρ[p]`` (Lawson & Hanson, 1974, ch. 23)."""
    from scipy.optimize import nnls  # on first use, like lsq_linear in solve_bounded

    p = rows.shape[1]
    stacked = np.vstack([rows.T, floors[None, :]])
    unit = np.zeros(p + 1)
    unit[p] = 1.0
    u, _ = nnls(stacked, unit, maxiter=50 * (p + 1) + 10 * rows.shape[0])
    residual = stacked @ u - unit
    if not residual[p] < -1e-12:  # ‖residual‖ ≈ 0: the rows are inconsistent
        return None
    return -residual[:p] / residual[p]


def _equality_solve(r: np.ndarray, rhs: np.ndarray, equal: np.ndarray, floors: np.ndarray) -> np.ndarray:
    """``min ‖R·x − c‖`` subject to ``equal·x = floors`` (least squares on the equalities' null space)."""
    if not equal.size:
        return np.linalg.lstsq(r, rhs, rcond=None)[0]
    base = np.linalg.lstsq(equal, floors, rcond=None)[0]
    basis = _null_space(equal)
    if not basis.size:
        return base
    return base + basis @ np.linalg.lstsq(r @ basis, rhs - r @ base, rcond=None)[0]


def _free_basis(active: np.ndarray, held_rows: np.ndarray) -> np.ndarray:
    """An orthonormal basis (``p × f``) of the directions the constraints that hold (the bounds of
    ``active`` and the rules ``held_rows``) leave free."""
    p = active.size
    rows = np.vstack([np.eye(p)[active != 0], held_rows.reshape(-1, p)])
    return _null_space(rows) if rows.size else np.eye(p)


def _null_space(rows: np.ndarray) -> np.ndarray:
    """An orthonormal basis (``p × f``) of the null space of ``rows`` (singular values below 1e-10
    of the largest count as zero)."""
    _, sv, vt = np.linalg.svd(rows)
    rank = int(np.count_nonzero(sv > 1e-10 * max(float(sv.max(initial=0.0)), 1e-300)))
    return vt[rank:].T


def _polish(r: np.ndarray, rhs: np.ndarray, lower: np.ndarray, upper: np.ndarray, x: np.ndarray,
            mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Finish the solver's answer exactly: take the bounds it (nearly) reached as active, solve the
    free parameters by least squares, and keep that if it is feasible and optimal (KKT: the
    gradient pushes every active parameter against its bound); else keep the solver's answer
    (bvls's own stopping test is on the cost, so an ill-conditioned ``R`` may leave it short)."""
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
                          penalty: np.ndarray | float, held_rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Covariances of the parameters.

    Args:
        design: prepared ``n × p`` design.
        free: boolean mask of the parameters not at a bound.
        s2: residual variance (per prepared row).
        penalty: λ + ridge per parameter.
        held_rows: the rules that hold (:attr:`BoundedSolution.held_rows`): the covariance is then
            the one on the null space of the constraints that hold.

    Returns:
        ``(cov_active, cov_full)``: the active-set covariance (zero rows/columns for parameters at
        a bound) and the covariance ignoring the bounds (used for one-sided intervals at a bound
        and for identifiability).
    """
    p = design.shape[1]
    info = information(design, penalty)
    cov_full = s2 * np.linalg.inv(info)
    cov_active = np.zeros((p, p))
    if held_rows is not None and held_rows.size:
        basis = _free_basis(np.where(free, 0, 1), held_rows)
        if basis.size:
            cov_active = s2 * basis @ np.linalg.inv(basis.T @ info @ basis) @ basis.T
        return cov_active, cov_full
    idx = np.flatnonzero(free)
    if idx.size:
        cov_active[np.ix_(idx, idx)] = s2 * np.linalg.inv(info[np.ix_(idx, idx)])
    return cov_active, cov_full


def hat_diagonal(design: np.ndarray, free: np.ndarray, penalty: np.ndarray | float,
                 held_rows: np.ndarray | None = None) -> np.ndarray:
    """Leverages ``h_ii`` of the rows on the free parameters (0 if none is free); with rules that
    hold (``held_rows``), on the directions the constraints leave free."""
    if held_rows is not None and held_rows.size:
        basis = _free_basis(np.where(free, 0, 1), held_rows)
        if not basis.size:
            return np.zeros(design.shape[0])
        d_b = design @ basis
        inner = basis.T @ information(design, penalty) @ basis
        return np.einsum("ij,ij->i", d_b @ np.linalg.inv(inner), d_b)
    idx = np.flatnonzero(free)
    if idx.size == 0:
        return np.zeros(design.shape[0])
    d_f = design[:, idx]
    info = information(design, penalty)[np.ix_(idx, idx)]
    return np.einsum("ij,ij->i", d_f @ np.linalg.inv(info), d_f)


def loo_residuals(design: np.ndarray, target: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                  solution: BoundedSolution, *, exact: bool, prior_weight: np.ndarray | float = 0.0,
                  prior_target: np.ndarray | None = None, ridge: float | None = None,
                  rules: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Leave-one-out residuals in prepared units: row i predicted by the fit without row i.

    Args:
        design, target, lower, upper, prior_weight, prior_target, ridge, rules: as for
            :func:`solve_bounded`.
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
        h = hat_diagonal(design, solution.active == 0, lam, solution.held_rows)
        return resid / np.maximum(1.0 - h, 1e-12)
    out = np.empty(n)
    keep = np.ones(n, dtype=bool)
    for i in range(n):
        keep[i] = False
        sol = solve_bounded(design[keep], target[keep], lower, upper, prior_weight=prior_weight,
                            prior_target=prior_target, ridge=ridge, rules=rules)
        keep[i] = True
        out[i] = design[i] @ sol.x - target[i]
    return out


def bootstrap(design: np.ndarray, target: np.ndarray, lower: np.ndarray, upper: np.ndarray,
              solution: BoundedSolution, *, samples: int, seed: int, dof: int,
              prior_weight: np.ndarray | float = 0.0, prior_target: np.ndarray | None = None,
              ridge: float | None = None, rules: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Residual-bootstrap 95 % percentile intervals, ``p × 2`` (prepared units).

    The residuals of the fit are centred, inflated by ``sqrt(n/dof)`` and resampled with
    replacement onto the fitted values; each resample is solved within the bounds (and ``rules``).
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
                                 prior_target=prior_target, ridge=ridge, rules=rules).x
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
