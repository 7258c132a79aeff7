"""Propagation: Phi against finite differences of the RK4 mean; Qd against closed forms."""

from __future__ import annotations

import numpy as np

from runtime.msckf.propagator import propagate_interval, select_samples
from runtime.msckf.so3_kernels import exp3, log3

G = np.array([0.0, 0.0, -9.81])


def _inputs(n: int = 41, dt: float = 0.0025, seed: int = 0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    w = (
        np.array([0.3, -0.5, 0.8])
        + 0.2 * np.sin(np.outer(t, [3.0, 5.0, 7.0]))
        + 0.01 * rng.standard_normal((n, 3))
    )
    a = np.array([0.5, -0.2, 9.9]) + 0.5 * np.cos(np.outer(t, [2.0, 4.0, 6.0]))
    return t, w, a


def _mean(x: tuple, t, w, a):
    R, p, v, bg, ba = x
    R1, p1, v1, _, _, _ = propagate_interval(
        R, p, v, bg, ba, R, p, v, False, t, w, a, G, 1e-3, 1e-2, 1e-4, 1e-3
    )
    return R1, p1, v1, bg, ba


def _boxminus(x1: tuple, x0: tuple) -> np.ndarray:
    return np.concatenate([log3(x0[0].T @ x1[0]), x1[1] - x0[1], x1[2] - x0[2], x1[3] - x0[3], x1[4] - x0[4]])


def _boxplus(x: tuple, d: np.ndarray) -> tuple:
    return (x[0] @ exp3(d[0:3]), x[1] + d[3:6], x[2] + d[6:9], x[3] + d[9:12], x[4] + d[12:15])


def test_phi_matches_finite_differences_of_rk4_mean() -> None:
    t, w, a = _inputs()
    x0 = (
        exp3(np.array([0.1, -0.2, 0.3])),
        np.array([1.0, 2.0, 3.0]),
        np.array([0.5, -0.3, 0.2]),
        np.array([0.01, -0.02, 0.015]),
        np.array([0.05, 0.02, -0.04]),
    )
    R, p, v, bg, ba = x0
    _, _, _, Phi, _, _ = propagate_interval(
        R, p, v, bg, ba, R, p, v, True, t, w, a, G, 1e-3, 1e-2, 1e-4, 1e-3
    )
    x1 = _mean(x0, t, w, a)
    num = np.zeros((15, 15))
    eps = 1e-6
    for j in range(15):
        d = np.zeros(15)
        d[j] = eps
        xp = _mean(_boxplus(x0, d), t, w, a)
        xm = _mean(_boxplus(x0, -d), t, w, a)
        num[:, j] = (_boxminus(xp, x1) - _boxminus(xm, x1)) / (2 * eps)
    # the analytic bias blocks hold inputs constant within each 2.5 ms interval: agree to ~1e-4 relative
    assert np.allclose(Phi, num, atol=2e-5 * np.abs(num).max() + 1e-7), np.abs(Phi - num).max()


def _unobservable(R: np.ndarray, p: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(15, 4) error-state directions the measurements cannot see at state (R, p, v): a rotation of the
    whole trajectory about gravity (right-perturbed attitude: dtheta = R^T g; dp = g x p, dv = g x v) and a
    global translation (Hesch et al. 2014, the property first-estimate Jacobians exist to keep)."""
    N = np.zeros((15, 4))
    N[0:3, 0] = R.T @ G
    N[3:6, 0] = np.cross(G, p)
    N[6:9, 0] = np.cross(G, v)
    N[3:6, 1:4] = np.eye(3)
    return N


def test_fej_transition_keeps_the_unobservable_directions() -> None:
    """With first estimates (R_f, p_f, v_f) at the start that differ from the current ones, the transition
    maps the unobservable directions at the start's first estimates onto those at the propagated state
    (which becomes the next first estimate); linearised at the current estimates instead, it does not,
    and the filter would gain spurious information about heading and global position."""
    t, w, a = _inputs()
    R = exp3(np.array([0.1, -0.2, 0.3]))
    p, v, z = np.array([1.0, 2.0, 3.0]), np.array([0.5, -0.3, 0.2]), np.zeros(3)
    R_f, p_f, v_f = R @ exp3(np.array([0.01, 0.0, -0.01])), p + 0.05, v - 0.02
    R1, p1, v1, Phi, _, _ = propagate_interval(
        R, p, v, z, z, R_f, p_f, v_f, True, t, w, a, G, 1e-3, 1e-2, 1e-4, 1e-3
    )
    N1 = _unobservable(R1, p1, v1)
    scale = np.abs(N1).max()
    assert np.abs(Phi @ _unobservable(R_f, p_f, v_f) - N1).max() < 1e-9 * scale
    # without first estimates (linearised at the current start state) the directions are not preserved
    _, _, _, Phi_cur, _, _ = propagate_interval(
        R, p, v, z, z, R, p, v, True, t, w, a, G, 1e-3, 1e-2, 1e-4, 1e-3
    )
    assert np.abs(Phi_cur @ _unobservable(R_f, p_f, v_f) - N1).max() > 1e-3 * scale


def test_qd_matches_closed_form_at_rest() -> None:
    # identity attitude, zero rates and specific force exactly cancelling gravity: along z the error
    # dynamics decouple from attitude: dv_z' = -dba_z - n_a, dp_z' = dv_z, dba' = n_wa; and
    # dtheta' = -dbg - n_g, dbg' = n_wg (closed-form covariances of integrated white noise)
    n, dt = 401, 0.0025
    t = np.arange(n) * dt
    w = np.zeros((n, 3))
    a = np.tile([0.0, 0.0, 9.81], (n, 1))
    sg, sa, swg, swa = 1e-3, 2e-2, 1e-4, 3e-3
    z = np.zeros(3)
    _, _, _, _, Q, _ = propagate_interval(
        np.eye(3), z, z, z, z, np.eye(3), z, z, True, t, w, a, G, sg, sa, swg, swa
    )
    T = t[-1]
    assert np.isclose(Q[0, 0], sg**2 * T + swg**2 * T**3 / 3, rtol=1e-3)
    assert np.isclose(Q[8, 8], sa**2 * T + swa**2 * T**3 / 3, rtol=1e-3)
    assert np.isclose(Q[5, 5], sa**2 * T**3 / 3 + swa**2 * T**5 / 20, rtol=2e-3)
    assert np.isclose(Q[5, 8], sa**2 * T**2 / 2 + swa**2 * T**4 / 8, rtol=2e-3)
    # horizontal velocity picks up the tilt error through gravity: dv_x' = g dtheta_y + ...
    assert Q[6, 6] > Q[8, 8] and np.isclose(Q[6, 6], Q[7, 7], rtol=1e-9)
    assert np.isclose(Q[9, 9], swg**2 * T, rtol=1e-9)
    assert np.isclose(Q[0, 9], -(swg**2) * T**2 / 2, rtol=1e-3)


def test_select_samples_interpolates_end_points() -> None:
    t_ns = np.array([0, 10, 20, 30], dtype=np.int64) * 1_000_000
    w = np.arange(12, dtype=float).reshape(4, 3)
    a = -w
    t, ws, as_ = select_samples(t_ns, w, a, 5_000_000, 25_000_000)
    assert np.allclose(t, [0.0, 0.005, 0.015, 0.020])
    assert np.allclose(ws[0], 0.5 * (w[0] + w[1])) and np.allclose(ws[-1], 0.5 * (w[2] + w[3]))
    assert np.allclose(as_[1:3], a[1:3])
