"""Levenberg-Marquardt on the normal equations (runtime.msckf.normal_lm) against scipy least_squares."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize

from runtime.msckf.normal_lm import levenberg_marquardt


def _rosenbrock_like(n: int):
    """Residuals of a chained Rosenbrock function (minimum 0 at x = 1), its Jacobian."""
    def fun(x):
        return np.concatenate([10.0 * (x[1:] - x[:-1] ** 2), 1.0 - x[:-1]])

    def jac(x):
        J = np.zeros((2 * (n - 1), n))
        i = np.arange(n - 1)
        J[i, i] = -20.0 * x[:-1]
        J[i, i + 1] = 10.0
        J[n - 1 + i, i] = -1.0
        return J
    return fun, jac


def test_it_reaches_the_minimum_of_a_curved_valley_from_far_away() -> None:
    fun, jac = _rosenbrock_like(8)
    x0 = np.full(8, -1.2)
    out = levenberg_marquardt(fun, jac, x0, max_nfev=200, ftol=1e-14, xtol=1e-14)
    assert out.converged and out.nfev <= 200
    np.testing.assert_allclose(out.x, 1.0, atol=1e-6)
    # the same problem and start through scipy's trust-region solver: the same minimum
    ref = scipy.optimize.least_squares(fun, x0, jac=jac, ftol=1e-14, xtol=1e-14, max_nfev=200)
    np.testing.assert_allclose(out.x, ref.x, atol=1e-6)


def test_a_noisy_fit_matches_scipy_and_the_linear_least_squares_optimum() -> None:
    # an exponential decay with noise: nonlinear in its rate; at the optimum the linear sub-problem
    # (amplitude, offset) equals the closed-form linear least-squares fit at that rate
    rng = np.random.default_rng(4)
    t = np.linspace(0.0, 4.0, 60)
    y = 2.5 * np.exp(-1.3 * t) + 0.4 + rng.normal(0, 0.02, t.size)

    def fun(p):
        return p[0] * np.exp(-p[1] * t) + p[2] - y

    def jac(p):
        e = np.exp(-p[1] * t)
        return np.column_stack([e, -p[0] * t * e, np.ones_like(t)])

    out = levenberg_marquardt(fun, jac, np.array([1.0, 0.5, 0.0]), max_nfev=100, ftol=1e-12, xtol=1e-12)
    ref = scipy.optimize.least_squares(fun, np.array([1.0, 0.5, 0.0]), jac=jac, ftol=1e-12, xtol=1e-12)
    assert out.converged
    np.testing.assert_allclose(out.x, ref.x, rtol=1e-6)
    A = np.column_stack([np.exp(-out.x[1] * t), np.ones_like(t)])
    np.testing.assert_allclose(out.x[[0, 2]], np.linalg.lstsq(A, y, rcond=None)[0], rtol=1e-6)
    assert out.cost == pytest.approx(ref.cost, rel=1e-9)


def test_the_evaluation_budget_and_non_finite_residuals() -> None:
    fun, jac = _rosenbrock_like(8)
    out = levenberg_marquardt(fun, jac, np.full(8, -1.2), max_nfev=3, ftol=1e-14, xtol=1e-14)
    assert out.nfev == 3 and not out.converged
    # residuals that turn non-finite away from the start: such steps are refused, the start kept finite
    out = levenberg_marquardt(lambda x: np.array([np.sqrt(x[0]) - 3.0]) if x[0] >= 0 else np.array([np.nan]),
                              lambda x: np.array([[0.5 / np.sqrt(max(x[0], 1e-12))]]),
                              np.array([0.01]), max_nfev=60, ftol=1e-15, xtol=1e-15)
    assert np.isfinite(out.cost) and out.x[0] == pytest.approx(9.0, rel=1e-6)
    # a start whose residual is not finite: returned at once, not converged
    nan = levenberg_marquardt(lambda x: np.array([np.nan]), lambda x: np.ones((1, 1)), np.zeros(1), 10,
                              1e-8, 1e-8)
    assert nan.nfev == 1 and not nan.converged


def test_a_start_at_the_minimum_ends_at_once_and_a_hopeless_search_ends_without_error() -> None:
    # a linear problem started at its least-squares solution: the first step is (numerically) zero
    rng = np.random.default_rng(7)
    A, y = rng.normal(size=(30, 4)), rng.normal(size=30)
    x_star = np.linalg.lstsq(A, y, rcond=None)[0]
    out = levenberg_marquardt(lambda x: A @ x - y, lambda x: A, x_star, max_nfev=60, ftol=1e-15, xtol=1e-15)
    assert out.converged and out.nfev <= 2
    np.testing.assert_allclose(out.x, x_star, rtol=0, atol=1e-12)
    assert out.cost <= 0.5 * float((A @ x_star - y) @ (A @ x_star - y))
    # at an exact zero of the gradient there is no step to evaluate
    zero = levenberg_marquardt(lambda x: x - 2.0, lambda x: np.eye(3), np.full(3, 2.0), 60, 1e-15, 1e-15)
    assert zero.converged and zero.nfev == 1
    # every step away from the start is refused (non-finite residuals there): the damping grows until the
    # steps vanish, with no overflow into a non-finite factorisation, and the start is returned
    x0 = np.array([1.0, 2.0])

    def only_here(x):
        return np.array([3.0, 4.0]) if np.array_equal(x, x0) else np.full(2, np.nan)

    stuck = levenberg_marquardt(only_here, lambda x: np.eye(2), x0, max_nfev=500, ftol=1e-15, xtol=1e-15)
    np.testing.assert_array_equal(stuck.x, x0)
    assert stuck.cost == 12.5 and stuck.nfev <= 500
    # every step short (xtol 1) and non-finite where it lands: not an end at a minimum, so not converged
    short = levenberg_marquardt(only_here, lambda x: np.eye(2), x0, max_nfev=500, ftol=1e-15, xtol=1.0)
    np.testing.assert_array_equal(short.x, x0)
    assert not short.converged


def test_the_last_short_step_is_kept_when_it_lowers_the_cost() -> None:
    # More, Garbow & Hillstrom's badly scaled Brown function (minimum 0 at (1e6, 2e-6)): the step that meets
    # xtol still lowers the cost by orders of magnitude, and scipy keeps it; ending before evaluating it
    # left the cost at 3.4e-8
    def fun(x):
        return np.array([x[0] - 1e6, x[1] - 2e-6, x[0] * x[1] - 2.0])

    def jac(x):
        return np.array([[1.0, 0.0], [0.0, 1.0], [x[1], x[0]]])

    out = levenberg_marquardt(fun, jac, np.ones(2), max_nfev=500, ftol=1e-8, xtol=1e-8)
    ref = scipy.optimize.least_squares(fun, np.ones(2), jac=jac, ftol=1e-8, xtol=1e-8, max_nfev=500)
    assert out.converged and out.cost < 1e-12 and ref.cost < 1e-12
    np.testing.assert_allclose(out.x, [1e6, 2e-6], rtol=1e-6)


def test_the_damping_shrinks_to_a_floor_a_refusal_can_grow_it_from(monkeypatch) -> None:
    # An undamped start (lambda 0) whose first step is taken; the Jacobian then understates the slope ten
    # times, so the undamped step overshoots and only lambda > 4 lowers the cost. A lambda shrunk to zero
    # would stay zero however often it is doubled, and the budget would run out on the same refused step.
    import runtime.msckf.normal_lm as normal_lm
    monkeypatch.setattr(normal_lm, "INITIAL_DAMPING", 0.0)
    calls = []

    def jac(x):
        calls.append(1)
        return np.eye(2) * (1.05 if len(calls) == 1 else 0.1)

    out = normal_lm.levenberg_marquardt(lambda x: x - 1.0, jac, np.full(2, 3.0), 400, 1e-12, 1e-12)
    assert out.converged and out.nfev < 400
    np.testing.assert_allclose(out.x, 1.0, atol=1e-5)
