"""The bounded solver core on plain matrices: optimality against an exact active-set method."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import lsq_linear

from hdeem_watch.calibrate.solve import solve_bounded, variance_reduction


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(2, 40), p=st.integers(1, 7))
def test_bounded_solution_is_optimal_and_feasible(seed: int, n: int, p: int) -> None:
    """For random problems (also with fewer rows than unknowns) the answer lies within the bounds,
    reaches the optimum of an exact active-set solver (BVLS) up to the tiny ridge, and its active
    set matches the bounds it sits on."""
    rng = np.random.default_rng(seed)
    design = rng.standard_normal((n, p)) * rng.uniform(0.1, 10, p)
    target = rng.standard_normal(n) * 3
    lower = -rng.uniform(0, 1, p)
    upper = rng.uniform(0.05, 1, p)
    sol = solve_bounded(design, target, lower, upper, ridge=1e-14)
    assert np.all(sol.x >= lower) and np.all(sol.x <= upper)
    ref = lsq_linear(design, target, bounds=(lower, upper), method="bvls")
    cost = 0.5 * np.sum((design @ sol.x - target) ** 2)
    assert cost <= ref.cost + 1e-7 * max(1.0, ref.cost)
    assert np.all(sol.x[sol.active == -1] == lower[sol.active == -1])
    assert np.all(sol.x[sol.active == 1] == upper[sol.active == 1])


def test_variance_reduction_matches_refitting_the_information() -> None:
    """Sherman–Morrison score equals 1 − var'/var computed by inverting M + r rᵀ directly."""
    rng = np.random.default_rng(3)
    design = rng.standard_normal((12, 4))
    info = design.T @ design + 1e-9 * np.eye(4)
    rows = rng.standard_normal((5, 4))
    scores = variance_reduction(info, rows, 2)
    var = np.linalg.inv(info)[2, 2]
    for row, score in zip(rows, scores):
        new = np.linalg.inv(info + np.outer(row, row))[2, 2]
        assert score == pytest.approx(1 - new / var, abs=1e-10)


def test_directions_no_run_sees_stay_exactly_at_the_prior_target() -> None:
    """One run that sees three of eight unknowns, the ridge pulling toward the prior target at the
    upper bound (the datasheet, as the calibrator scales it): the five unseen unknowns land exactly
    on that target, the seen ones fit the run. (An interior-point solver stopped 4·10⁻⁴ short of
    the bound here, on a problem the calibrator met at its first runs.)"""
    p = 8
    design = np.zeros((1, p))
    design[0, [1, 2, 5]] = [0.1162, -0.136, 1.4768]
    lower, upper = np.zeros(p), np.ones(p)
    sol = solve_bounded(design, np.array([0.1612]), lower, upper, prior_weight=0.0,
                        prior_target=np.ones(p), ridge=3.2e-12)
    unseen = [0, 3, 4, 6, 7]
    assert np.all(sol.x[unseen] == 1.0)
    assert np.all(sol.active[unseen] == 1)
    assert float(design[0] @ sol.x) == pytest.approx(0.1612, abs=1e-9)
