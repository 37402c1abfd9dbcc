"""Batch calibration: fit chosen DRAM currents (and an intercept) to measured run energies.

Rows are :class:`~hdeem_watch.calibrate.observation.Observation` s. The currents not chosen stay at
their memspec values and move into each row's constant. The problem solved is

    minimise  Σ_i w_i ((Σ_j c_ij I_j + k_i + b − m_i) / m_i)²   (+ prior)
    subject to lower_j ≤ I_j ≤ upper_j (default 0..datasheet, narrowed to the physically
               consistent limits of :mod:`hdeem_watch.calibrate.physical`),  b ≥ 0

i.e. *relative* residuals (measurement error grows with the energy; every run counts alike
whatever its length), on columns scaled by the datasheet value, so every unknown is a fraction of
its datasheet value and the condition number speaks about relative changes. The intercept ``b`` (J
per run) stands for what the model does not cover. See :mod:`hdeem_watch.calibrate.solve` for the
solver, covariance and leave-one-out, and :mod:`hdeem_watch.calibrate.observe` for what the data
determine.

Example:
    >>> import numpy as np
    >>> spec = type("Spec", (), {"currents": {"a": 2.0, "b": 1.0}})()
    >>> truth = np.array([1.0, 0.5])
    >>> rows = [Observation(f"r{i}", np.array(c), 0.0, float(np.dot(c, truth)))
    ...         for i, c in enumerate([[1.0, 2.0], [3.0, 1.0], [2.0, 2.0]])]
    >>> result = fit(rows, spec, FitOptions(currents=("a", "b"), intercept=False, names=("a", "b")))
    >>> [round(float(v), 6) for v in result.calibrated_a]
    [1.0, 0.5]
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hdeem_watch.calibrate import solve
from hdeem_watch.calibrate.observation import (
    DEFAULT_CURRENTS,
    Observation,
    SpecLike,
    current_names,
    stack,
)
from hdeem_watch.calibrate.physical import PhysicalLimits, physical_limits
from hdeem_watch.calibrate.result import FitModel, FitResult, FitSettings
from hdeem_watch.dram.memspec import MAX_DEVICE_CURRENT_A
from hdeem_watch.errors import InputError

__all__ = ["LOO_EXACT_MAX_RUNS", "FitModel", "FitOptions", "FitResult", "FitSettings", "fit"]

#: ``loo="auto"`` refits exactly up to this many runs and uses the hat-matrix identity above.
LOO_EXACT_MAX_RUNS = 60


UNCERTAINTY_METHODS = ("analytic", "bootstrap")
LOO_METHODS = ("auto", "exact", "hat", "none")


@dataclass(frozen=True)
class FitOptions:
    """How :func:`fit` calibrates: which currents, their bounds, the intercept, prior and errors.

    Attributes:
        currents: names of the currents to calibrate (memspec keys, any case; a single name is
            taken as a one-element tuple).
        bounds: ``{name: (lower_a, upper_a)}`` overriding the default ``(0, datasheet)``.
        physical: narrow the default bounds to the physically consistent limits against the
            currents not calibrated (:func:`~hdeem_watch.calibrate.physical.physical_limits`;
            e.g. IDD3N ≥ IDD3P); explicit ``bounds`` are taken as given.
        rules: also keep the ordering rules *between* calibrated currents (IDD3N ≥ IDD2N, IDD0
            above the tRAS/tRC mix of IDD3N and IDD2N, ...), so the calibrated memspec is
            physical. Off by default: fitted currents are *effective* ones that absorb what the
            model gets wrong (the seed paper's own calibration has IDD3N < IDD2N), and holding
            them to the rules costs accuracy (docs/calibration.md). Rules that contradict the
            bounds are dropped.
        intercept: fit a per-run energy ``≥ 0`` the model does not cover (else it is 0).
        prior_weight: λ of a Gaussian prior toward the datasheet on the relative currents; 1 means
            a 100 % deviation costs as much as a 100 % error on one run. 0 = off.
        uncertainty: ``"analytic"`` (active-set covariance, t quantile) or ``"bootstrap"``.
        loo: ``"auto"``, ``"exact"`` (n refits), ``"hat"`` (hat-matrix identity) or ``"none"``.
        names: the order of the observation columns (None: ``energy.CURRENT_NAMES``).
        bootstrap_samples: resamples for ``uncertainty="bootstrap"``.
        seed: random seed of the bootstrap.
        require_overdetermined: raise if there are fewer runs than unknowns (the online
            calibrator fits from the first run on and turns this off).
        settings: identifiability thresholds.

    Raises:
        InputError: an unknown ``uncertainty`` or ``loo`` method.

    Example:
        >>> options = FitOptions(currents="IDD3N", intercept=False)
        >>> options.currents, options.loo
        (('IDD3N',), 'auto')
    """

    currents: Sequence[str] = DEFAULT_CURRENTS
    bounds: Mapping[str, tuple[float, float]] | None = None
    physical: bool = True
    rules: bool = False
    intercept: bool = True
    prior_weight: float = 0.0
    uncertainty: str = "analytic"
    loo: str = "auto"
    names: Sequence[str] | None = None
    bootstrap_samples: int = 200
    seed: int = 0
    require_overdetermined: bool = True
    settings: FitSettings = field(default_factory=FitSettings)

    def __post_init__(self) -> None:
        currents = (self.currents,) if isinstance(self.currents, str) else tuple(self.currents)
        object.__setattr__(self, "currents", currents)
        if self.names is not None:
            object.__setattr__(self, "names", tuple(self.names))
        if self.bounds is not None:
            object.__setattr__(self, "bounds", dict(self.bounds))
        if self.uncertainty not in UNCERTAINTY_METHODS:
            raise InputError(f"uncertainty: {self.uncertainty!r}; expected 'analytic' or 'bootstrap'")
        if self.loo not in LOO_METHODS:
            raise InputError(f"loo: {self.loo!r}; expected auto, exact, hat or none")


def fit(observations: Sequence[Observation], spec: SpecLike, options: FitOptions | None = None, *,
        weights: np.ndarray | None = None, time_ns: int = 0) -> FitResult:
    """Fit the chosen currents (and an intercept ≥ 0) to the measured energies of ``observations``.

    Args:
        observations: the runs (at least as many as unknowns unless
            ``options.require_overdetermined`` is False).
        spec: the memspec (a :class:`~hdeem_watch.dram.memspec.MemSpec`, or anything with its
            ``currents``: the datasheet values and the fixed currents).
        options: what to fit and how (default: :class:`FitOptions` ()).
        weights: extra per-run factors on top of each observation's ``weight`` (e.g. forgetting).
        time_ns: time stamp recorded in the result.

    Raises:
        InputError: an unknown current, bad bounds, no runs, or fewer runs than unknowns.
    """
    options = options or FitOptions()
    problem = _prepare(observations, spec, options, weights)
    sol = solve.solve_bounded(problem.design, problem.target, problem.lower, problem.upper, **problem.solver)
    k, p, n, intercept = problem.k, problem.p, problem.n, problem.intercept
    # Fewer runs than unknowns: the bounds the exact solver lands on are the data's choice, not
    # knowledge, so the residual variance (and every interval built on it) stays unknown.
    dof = int(np.count_nonzero(problem.weight > 0)) - sol.free_dimension if n >= p else 0
    s2 = sol.rss / dof if dof > 0 else math.nan
    ci, method = _uncertainty(problem, sol, options, s2, dof)
    param_scale = np.concatenate([problem.scales, [problem.b_scale] if intercept else []])
    params = sol.x * param_scale
    ci_units = ci * param_scale[:, None]

    sv, rank, cond, correlation = _observability(problem.design, problem.singular_values, p,
                                                 options.settings.rank_tol)
    sensitivity, identifiable = _identifiable(problem.design, problem.raw[:, :k] / problem.measured[:, None],
                                              sol.x[:k], s2, problem.penalty, options.settings)

    # Errors: datasheet model, calibrated model, leave-one-out.
    measured = problem.measured
    before_j = problem.cols @ problem.all_a + problem.const
    after_j = problem.x_a @ params[:k] + problem.const_eff + (params[k] if intercept else 0.0)
    loo_j = _loo_energies(problem, sol, options.loo)
    at_bound = tuple({-1: "lower", 1: "upper"}.get(int(a)) for a in sol.active[:k])
    couplings = problem.limits.couplings if problem.limits and problem.rules else ()
    rules_held = tuple(c.rule for c, held in zip(couplings, sol.held) if held)
    status = "underdetermined" if n < p else "rank-deficient" if rank < p else "ok"
    if status == "ok" and (any(at_bound) or rules_held):
        status = "at-bound"
    return FitResult(
        currents=problem.chosen,
        datasheet_a=problem.datasheet,
        calibrated_a=params[:k],
        ci95_a=ci_units[:k],
        identifiable=identifiable,
        at_bound=at_bound,
        rules_held=rules_held,
        sensitivity=sensitivity,
        intercept_fitted=intercept,
        intercept_j=float(params[k]) if intercept else 0.0,
        intercept_ci95_j=(float(ci_units[k, 0]), float(ci_units[k, 1])) if intercept else (0.0, 0.0),
        error_before=_mare(before_j, measured),
        error_after=_mare(after_j, measured),
        error_loo=_mare(loo_j, measured),
        singular_values=sv,
        condition_number=cond,
        rank=rank,
        correlation=correlation,
        n_runs=n,
        dof=dof,
        noise_rel=math.sqrt(s2) if not math.isnan(s2) else math.nan,
        status=status,
        uncertainty=method,
        runs=_run_rows(observations, measured, before_j, after_j, loo_j, problem.weight),
        time_ns=time_ns,
        model=FitModel(spec=spec, names=problem.names, index=problem.index, scales_a=problem.scales,
                       intercept_scale_j=problem.b_scale, info=solve.information(problem.design, problem.penalty),
                       params=params),
    )


@dataclass(frozen=True)
class _Problem:
    """The bounded least-squares problem :func:`fit` solves, prepared: relative rows (each run's
    residual divided by its measured energy, times the square root of its weight), columns scaled
    by the datasheet value (unknowns are fractions of it), the intercept scaled by the median run."""

    names: tuple[str, ...]
    chosen: tuple[str, ...]
    index: np.ndarray  # the chosen currents' columns among ``names``
    all_a: np.ndarray  # the memspec's value of every current
    limits: PhysicalLimits | None
    rules: tuple[np.ndarray, np.ndarray] | None  # the couplings as solver rules (None: not kept)
    cols: np.ndarray  # per run and current: the energy per ampere
    const: np.ndarray  # per run: the energy no current covers
    const_eff: np.ndarray  # ... plus the currents not fitted, at their memspec values
    measured: np.ndarray
    weight: np.ndarray  # normalised to a mean of 1 over the weighted runs
    raw: np.ndarray  # the scaled columns before the row factors
    design: np.ndarray
    target: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    prior_target: np.ndarray
    prior_weight: np.ndarray
    ridge: float
    singular_values: np.ndarray
    scales: np.ndarray
    b_scale: float
    intercept: bool

    @property
    def k(self) -> int:
        """The number of fitted currents."""
        return len(self.chosen)

    @property
    def p(self) -> int:
        """The number of unknowns (currents and the intercept)."""
        return self.k + int(self.intercept)

    @property
    def n(self) -> int:
        """The number of runs."""
        return int(self.measured.size)

    @property
    def datasheet(self) -> np.ndarray:
        """The fitted currents' memspec values."""
        return self.all_a[self.index]

    @property
    def x_a(self) -> np.ndarray:
        """The fitted currents' columns."""
        return self.cols[:, self.index]

    @property
    def penalty(self) -> np.ndarray:
        """The diagonal the prior and the ridge add to the information."""
        return self.prior_weight + self.ridge

    @property
    def row(self) -> np.ndarray:
        """Each run's row factor (its weight's root over its measured energy)."""
        return np.sqrt(self.weight) / self.measured

    @property
    def solver(self) -> dict[str, Any]:
        """The prior, ridge and rules, as the solver's keyword arguments."""
        return {"prior_weight": self.prior_weight, "prior_target": self.prior_target, "ridge": self.ridge,
                "rules": self.rules}


def _prepare(observations: Sequence[Observation], spec: SpecLike, options: FitOptions,
             weights: np.ndarray | None) -> _Problem:
    """Check the request and build the prepared problem (see :class:`_Problem`)."""
    intercept = options.intercept
    names = tuple(options.names) if options.names is not None else current_names(spec)
    chosen = _check_currents(options.currents, names, spec)
    if not observations:
        raise InputError("runs: no runs to calibrate on")
    k, n = len(chosen), len(observations)
    p = k + int(intercept)
    if options.require_overdetermined and n < p:
        raise InputError(f"runs: {n} runs for {p} unknowns ({', '.join(chosen)}"
                         f"{', intercept' if intercept else ''}); need at least {p}")
    cols, const, measured, weight = stack(observations, len(names))
    if weights is not None:
        weight = weight * np.asarray(weights, dtype=float)
    if not np.any(weight > 0):
        raise InputError("runs: every run has weight 0")
    weight = weight / weight[weight > 0].mean()

    index = np.array([names.index(c) for c in chosen], dtype=int)
    all_a = np.array([float(spec.currents.get(nm, 0.0)) for nm in names])
    datasheet = all_a[index]
    used = {name for name, seen in zip(names, np.any(cols != 0, axis=0)) if seen}
    # With the rules kept, every rule holds (a memspec DRAMPower and the memspec check accept), also
    # those against a current whose state no run uses (IDD3N ≥ IDD3P without power-down residency).
    limits = physical_limits(spec, chosen, None if options.rules else used) if options.physical or options.rules else None
    lower_a, upper_a = _bounds(chosen, datasheet, options.bounds, limits.bounds if limits and options.physical else None)
    scales = np.where(datasheet > 0, datasheet, np.where(np.isfinite(upper_a) & (upper_a > 0), upper_a, 1.0))
    fixed = np.ones(len(names), dtype=bool)
    fixed[index] = False
    const_eff = const + cols[:, fixed] @ all_a[fixed]
    b_scale = float(np.median(measured)) if intercept else 0.0

    row = np.sqrt(weight) / measured
    raw = np.hstack([cols[:, index] * scales, np.ones((n, 1)) * b_scale]) if intercept else cols[:, index] * scales
    design = raw * row[:, None]
    lower = np.concatenate([lower_a / scales, [0.0] if intercept else []])
    upper = np.concatenate([upper_a / scales, [np.inf] if intercept else []])
    x0 = np.concatenate([datasheet / scales, [0.0] if intercept else []])
    sv = np.linalg.svd(design, compute_uv=False)
    return _Problem(
        names=names, chosen=chosen, index=index, all_a=all_a, limits=limits,
        rules=_rules(limits, scales, int(intercept)) if options.rules else None,
        cols=cols, const=const, const_eff=const_eff, measured=measured, weight=weight, raw=raw, design=design,
        target=(measured - const_eff) * row, lower=lower, upper=upper, prior_target=np.clip(x0, lower, upper),
        prior_weight=np.concatenate([np.full(k, float(options.prior_weight)), [0.0] if intercept else []]),
        ridge=solve.RIDGE_RELATIVE * max(float(sv.max()) ** 2 if sv.size else 0.0, 1e-300),
        singular_values=sv, scales=scales, b_scale=b_scale, intercept=intercept)


def _uncertainty(problem: _Problem, sol: solve.BoundedSolution, options: FitOptions, s2: float,
                 dof: int) -> tuple[np.ndarray, str]:
    """The 95 % intervals of the prepared parameters (``p × 2``) and the method's name."""
    if options.uncertainty == "bootstrap" and dof > 0:
        ci = solve.bootstrap(problem.design, problem.target, problem.lower, problem.upper, sol,
                             samples=options.bootstrap_samples, seed=options.seed, dof=dof, **problem.solver)
        return ci, f"residual-bootstrap-{options.bootstrap_samples}"
    cov_active, cov_full = solve.active_set_covariance(problem.design, sol.active == 0, 1.0 if math.isnan(s2) else s2,
                                                       problem.penalty, sol.held_rows)
    return _intervals(sol, problem.lower, problem.upper, cov_active, cov_full, s2, dof), "analytic-active-set"


def _loo_energies(problem: _Problem, sol: solve.BoundedSolution, loo: str) -> np.ndarray:
    """Each run's energy predicted by the fit without it (NaN where there is none)."""
    n = problem.n
    if loo == "none" or n < 2:
        return np.full(n, np.nan)
    exact = loo == "exact" or (loo == "auto" and n <= LOO_EXACT_MAX_RUNS)
    row = problem.row
    with np.errstate(divide="ignore", invalid="ignore"):
        residuals = solve.loo_residuals(problem.design, problem.target, problem.lower, problem.upper, sol,
                                        exact=exact, **problem.solver)
        return np.where(row > 0, problem.measured + residuals / np.where(row > 0, row, 1.0), np.nan)


def _observability(design: np.ndarray, sv: np.ndarray, p: int,
                   rank_tol: float) -> tuple[np.ndarray, int, float, np.ndarray]:
    """Observability of the prepared design (relative rows, datasheet-scaled columns): its ``p``
    singular values (zero-padded), rank, condition number and column correlation (NaN for a column
    that is all zero)."""
    sv = np.concatenate([sv, np.zeros(max(0, p - sv.size))])
    rank = int(np.count_nonzero(sv > rank_tol * (sv.max() if sv.size else 0.0)))
    cond = float(sv.max() / sv.min()) if sv.size and sv.min() > 0 else math.inf
    norms = np.linalg.norm(design, axis=0)
    safe = np.where(norms > 0, norms, 1.0)
    correlation = (design.T @ design) / np.outer(safe, safe)
    correlation[norms == 0, :] = np.nan
    correlation[:, norms == 0] = np.nan
    return sv, rank, cond, correlation


def _identifiable(design: np.ndarray, rel_cols: np.ndarray, x: np.ndarray, s2: float, penalty: np.ndarray,
                  settings: FitSettings) -> tuple[np.ndarray, np.ndarray]:
    """Each current's sensitivity (RMS of its relative columns ``rel_cols``) and whether it is
    identifiable: sensitive enough and its 95 % half-width, relative to its prepared value ``x``
    (at least 5 % of its scale), within ``settings.max_rel_ci``."""
    k = rel_cols.shape[1]
    sensitivity = np.sqrt(np.mean(rel_cols ** 2, axis=0))
    sigma = max(math.sqrt(s2) if not math.isnan(s2) else 0.0, settings.noise_floor)
    unit_cov = np.linalg.inv(solve.information(design, penalty))
    reference = np.maximum(np.abs(x), 0.05)
    half_rel = 1.96 * sigma * np.sqrt(np.diag(unit_cov)[:k]) / reference
    return sensitivity, (sensitivity >= settings.min_sensitivity) & (half_rel <= settings.max_rel_ci)


def _run_rows(observations: Sequence[Observation], measured: np.ndarray, before_j: np.ndarray,
              after_j: np.ndarray, loo_j: np.ndarray, weight: np.ndarray) -> tuple[dict[str, Any], ...]:
    """Per run: name, measured, datasheet-model, calibrated-model and leave-one-out energies (None
    where there is no leave-one-out value) and weight."""
    loo_list = [v if v == v and abs(v) != math.inf else None for v in loo_j.tolist()]
    return tuple(
        {"name": obs.name, "measured_j": m, "before_j": b, "after_j": a, "loo_j": lo, "weight": w}
        for obs, m, b, a, lo, w in zip(observations, measured.tolist(), before_j.tolist(), after_j.tolist(),
                                       loo_list, weight.tolist()))


def _rules(limits: PhysicalLimits | None, scales: np.ndarray, n_extra: int) -> tuple[np.ndarray, np.ndarray] | None:
    """The couplings as solver rules ``G·x ≥ h`` on the prepared (scaled) parameters."""
    if limits is None or not limits.couplings:
        return None
    g = np.array([[*(np.asarray(c.coefficients) * scales), *([0.0] * n_extra)] for c in limits.couplings])
    return g, np.array([c.floor_a for c in limits.couplings])


def _check_currents(currents: Sequence[str], names: tuple[str, ...], spec: SpecLike) -> tuple[str, ...]:
    chosen: list[str] = []
    for raw in currents:
        name = str(raw).strip().lower()
        if name not in names or name not in spec.currents:
            known = [nm for nm in names if nm in spec.currents]
            raise InputError(f"currents: unknown current {raw!r}; expected some of {', '.join(known)}")
        if name not in chosen:
            chosen.append(name)
    if not chosen:
        raise InputError("currents: no current chosen to calibrate")
    return tuple(chosen)


def _bounds(chosen: tuple[str, ...], datasheet: np.ndarray, bounds: Mapping[str, tuple[float, float]] | None,
            physical: Mapping[str, tuple[float, float]] | None = None) -> tuple[np.ndarray, np.ndarray]:
    lower = np.zeros(len(chosen))
    upper = datasheet.astype(float).copy()
    for j, name in enumerate(chosen):
        lo, hi = (physical or {}).get(name, (0.0, math.inf))
        lo, hi = max(lower[j], lo), min(upper[j], hi)
        if lo < hi:  # an empty range would mean the memspec itself is unphysical: keep the default
            lower[j], upper[j] = lo, hi
    for name in bounds or {}:
        if name not in chosen:
            raise InputError(f"bounds: {name!r} is not a calibrated current ({', '.join(chosen)})")
    for j, name in enumerate(chosen):
        if bounds and name in bounds:
            try:
                lo, hi = (float(v) for v in bounds[name])
            except (TypeError, ValueError):
                raise InputError(f"bounds.{name}: {bounds[name]!r}; expected (lower_a, upper_a)") from None
            check_bound_a(f"bounds.{name}", lo, hi)
            lower[j], upper[j] = lo, hi
        if not (lower[j] < upper[j]):
            raise InputError(f"bounds.{name}: lower {lower[j]:g} A must be < upper {upper[j]:g} A"
                             f"{' (datasheet value is 0: give explicit bounds)' if datasheet[j] == 0 else ''}")
    return lower, upper


def check_bound_a(where: str, lower_a: float, upper_a: float) -> None:
    """Raise an InputError naming ``where`` unless ``0 <= lower_a < upper_a`` are plausible per-device
    currents in amperes (an upper bound above :data:`MAX_DEVICE_CURRENT_A` is milliamperes typed as
    amperes, as the memspec reader says of currents).

    Example:
        >>> check_bound_a("--bounds idd4r", 0.0, 200.0)
        Traceback (most recent call last):
        ...
        hdeem_watch.errors.InputError: --bounds idd4r: upper 200 A looks like mA; expected amperes per device (0.2)
    """
    if not (math.isfinite(lower_a) and math.isfinite(upper_a)):
        raise InputError(f"{where}: {lower_a:g}:{upper_a:g}; expected finite currents in amperes")
    if lower_a < 0:
        raise InputError(f"{where}: lower {lower_a:g} A is negative; expected a current >= 0 A")
    if not lower_a < upper_a:
        raise InputError(f"{where}: lower {lower_a:g} A must be < upper {upper_a:g} A")
    if upper_a > MAX_DEVICE_CURRENT_A:
        raise InputError(f"{where}: upper {upper_a:g} A looks like mA; expected amperes per device "
                         f"({upper_a / 1000:g})")


def _intervals(sol: solve.BoundedSolution, lower: np.ndarray, upper: np.ndarray, cov_active: np.ndarray,
               cov_full: np.ndarray, s2: float, dof: int) -> np.ndarray:
    p = sol.x.size
    if math.isnan(s2) or dof <= 0:
        return np.full((p, 2), np.nan)
    from scipy.special import stdtrit  # on first use, like scipy.optimize in solve.py (start-up time)

    q = float(stdtrit(dof, 0.975))  # the Student t quantile
    se_free = np.sqrt(np.maximum(np.diag(cov_active), 0.0))
    se_full = np.sqrt(np.maximum(np.diag(cov_full), 0.0))
    lo = np.where(sol.active == 0, sol.x - q * se_free, np.where(sol.active == 1, sol.x - q * se_full, sol.x))
    hi = np.where(sol.active == 0, sol.x + q * se_free, np.where(sol.active == -1, sol.x + q * se_full, sol.x))
    return np.column_stack([np.clip(lo, lower, upper), np.clip(hi, lower, upper)])


def _mare(predicted: np.ndarray, measured: np.ndarray) -> float:
    rel = np.abs(predicted - measured) / measured
    rel = rel[np.isfinite(rel)]
    return float(rel.mean()) if rel.size else math.nan
