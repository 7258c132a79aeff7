"""Levenberg-Marquardt on the normal equations, for small dense least-squares problems on the tracking thread.

The dynamic initializer's refinement has a few hundred parameters and residuals a few times as many; scipy's
trust-region solvers factor the whole (m, n) Jacobian at every step (SVD or QR: 25-35 ms on 2 cores for
655 x 210), where the (n, n) normal equations J^T J need a Cholesky factor of about 2 ms. The step solves
(J^T J + lambda diag(J^T J)) dx = -J^T r (Marquardt's scaling, so the damping does not depend on the units
of the parameters); lambda follows Nielsen's rule (Madsen, Nielsen & Tingleff, "Methods for non-linear
least squares problems", 2004, Sec. 3.2): shrunk by max(1/3, 1 - (2 rho - 1)^3) on a step whose gain ratio
rho is positive, grown by a doubling factor on one that is not. The ends test the cost as scipy
least_squares's does (an accepted step that lowers it by less than ftol of itself, with a gain ratio above
1/4), and the step: one shorter than xtol (xtol + |x|) is evaluated, kept when it lowers the cost, and ends
the search either way, as scipy's does; a zero step (a stationary point) ends it before any evaluation.
scipy's gradient test is not made.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.linalg

#: lambda of the first step: nearly the Gauss-Newton step, which a good start (the initializer's linear
#: solve) takes at once; a failing one grows lambda 2, 4, 8 ... times per rejection
INITIAL_DAMPING = 1e-6
#: lambda beyond which the search stops: steps damped this much no longer move x
MAX_DAMPING = 1e16


@dataclass(frozen=True)
class LmResult:
    """x: the solution; cost: 0.5 |r(x)|^2; nfev: residual evaluations; converged: an end test was met
    (False: the evaluations ran out, or no step could be taken)."""

    x: np.ndarray
    cost: float
    nfev: int
    converged: bool


def levenberg_marquardt(fun: Callable[[np.ndarray], np.ndarray], jac: Callable[[np.ndarray], np.ndarray],
                        x0: np.ndarray, max_nfev: int, ftol: float, xtol: float) -> LmResult:
    """Minimise 0.5 |fun(x)|^2 from x0 with the dense Jacobian `jac` (m, n), m >= n.

    max_nfev counts residual evaluations, the first included (a rejected step costs one, as in scipy).
    """
    x = np.asarray(x0, dtype=np.float64).copy()
    r = fun(x)
    cost = 0.5 * float(r @ r)
    nfev = 1
    if not np.isfinite(cost):
        return LmResult(x, cost, nfev, False)
    J = jac(x)
    lam, grow = INITIAL_DAMPING, 2.0
    while nfev < max_nfev:
        if not np.all(np.isfinite(J)):
            return LmResult(x, cost, nfev, False)
        H = J.T @ J
        g = J.T @ r
        scale = np.maximum(np.diag(H), 1e-12 * max(float(np.max(np.diag(H))), 1e-300))
        try:
            L = np.linalg.cholesky(H + lam * np.diag(scale))
        except np.linalg.LinAlgError:
            lam, grow = lam * grow, grow * 2.0
            if lam > MAX_DAMPING:
                return LmResult(x, cost, nfev, False)
            continue
        dx = scipy.linalg.cho_solve((L, True), -g)
        if not np.any(dx):              # a stationary point: no step to try
            return LmResult(x, cost, nfev, True)
        short = np.linalg.norm(dx) < xtol * (xtol + np.linalg.norm(x))
        x_new = x + dx
        r_new = fun(x_new)
        nfev += 1
        cost_new = 0.5 * float(r_new @ r_new)
        predicted = -float(g @ dx) - 0.5 * float(dx @ (H @ dx))
        rho = (cost - cost_new) / predicted if (predicted > 0 and np.isfinite(cost_new)) else -1.0
        if rho > 0:
            small = (cost - cost_new) < ftol * cost and rho > 0.25
            x, r, cost = x_new, r_new, cost_new
            if small or short:
                return LmResult(x, cost, nfev, True)
            # shrunk, but kept above zero so that a later refusal can grow it again (a safety net: from
            # INITIAL_DAMPING it takes hundreds of accepted steps to get there)
            lam, grow = max(lam * max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), 1e-300), 2.0
            if nfev < max_nfev:
                J = jac(x)
        else:
            if short and np.isfinite(cost_new):   # a step this short does not lower the cost: x is the end
                return LmResult(x, cost, nfev, True)
            lam, grow = lam * grow, grow * 2.0
            if lam > MAX_DAMPING:       # no step lowers the cost: x is as good as it gets here
                return LmResult(x, cost, nfev, False)
    return LmResult(x, cost, nfev, False)
