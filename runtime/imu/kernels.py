"""numba hot loops of IMU preintegration and state propagation (see preintegration.py for the maths)."""
from __future__ import annotations

import numpy as np
from numba import njit

from runtime.geometry.kernels import (
    nb_normalize_rotation,
    nb_right_jacobian,
    nb_skew,
    nb_so3_exp,
)


@njit(cache=True, nogil=True)
def nb_preintegrate(dts: np.ndarray, gyro: np.ndarray, accel: np.ndarray, bg: np.ndarray, ba: np.ndarray,
                    var_g: float, var_a: float, with_cov: bool, end_nodes: np.ndarray):
    """Preintegrate K intervals between K+1 nodes (midpoint scheme, see Preintegration).

    dts (K,) s; gyro, accel (K+1, 3) node measurements; bg, ba (3,) biases; var_g, var_a the squared
    continuous noise densities; end_nodes (E,) the node indices at which to report (node 0 = start).
    Returns, stacked over the E ends: dR (E,3,3), dv (E,3), dp (E,3), cov (E,9,9, order [phi, v, p]),
    J_R_bg, J_v_bg, J_v_ba, J_p_bg, J_p_ba (E,3,3).
    """
    n_end = end_nodes.shape[0]
    out_R = np.zeros((n_end, 3, 3))
    out_v = np.zeros((n_end, 3))
    out_p = np.zeros((n_end, 3))
    out_cov = np.zeros((n_end, 9, 9))
    out_J = np.zeros((5, n_end, 3, 3))
    eye3 = np.eye(3)
    dR = np.eye(3)
    dv = np.zeros(3)
    dp = np.zeros(3)
    J_R_bg = np.zeros((3, 3))
    J_v_bg = np.zeros((3, 3))
    J_v_ba = np.zeros((3, 3))
    J_p_bg = np.zeros((3, 3))
    J_p_ba = np.zeros((3, 3))
    cov = np.zeros((9, 9))
    A = np.eye(9)
    Bg = np.zeros((9, 3))
    Ba = np.zeros((9, 3))
    for e in range(n_end):
        if end_nodes[e] == 0:
            out_R[e] = dR
    for k in range(dts.shape[0]):
        dt = dts[k]
        w = 0.5 * (gyro[k] + gyro[k + 1]) - bg
        a = 0.5 * (accel[k] + accel[k + 1]) - ba
        phi = w * dt
        dR_k = nb_so3_exp(phi)
        H = nb_so3_exp(0.5 * phi)
        Jr = nb_right_jacobian(phi)
        Jr_half = nb_right_jacobian(0.5 * phi)
        R_half = dR @ H
        Ra = R_half @ nb_skew(a)
        acc = R_half @ a
        # bias Jacobians: derivatives of this discrete scheme, from the values before the step
        J_half = H.T @ J_R_bg - (0.5 * dt) * Jr_half
        RaJ = Ra @ J_half
        J_p_bg = J_p_bg + dt * J_v_bg - (0.5 * dt * dt) * RaJ
        J_p_ba = J_p_ba + dt * J_v_ba - (0.5 * dt * dt) * R_half
        J_v_bg = J_v_bg - dt * RaJ
        J_v_ba = J_v_ba - dt * R_half
        J_R_bg = dR_k.T @ J_R_bg - dt * Jr
        if with_cov:
            M = Ra @ H.T
            A[0:3, 0:3] = dR_k.T
            A[3:6, 0:3] = -dt * M
            A[6:9, 0:3] = (-0.5 * dt * dt) * M
            A[6:9, 3:6] = dt * eye3
            G = Ra @ Jr_half
            Bg[0:3, :] = dt * Jr
            Bg[3:6, :] = (-0.5 * dt * dt) * G
            Bg[6:9, :] = (-0.25 * dt * dt * dt) * G
            Ba[3:6, :] = dt * R_half
            Ba[6:9, :] = (0.5 * dt * dt) * R_half
            cov = A @ cov @ A.T + (var_g / dt) * (Bg @ Bg.T) + (var_a / dt) * (Ba @ Ba.T)
        dp = dp + dt * dv + (0.5 * dt * dt) * acc
        dv = dv + dt * acc
        dR = dR @ dR_k
        for e in range(n_end):
            if end_nodes[e] == k + 1:
                out_R[e] = nb_normalize_rotation(dR)
                out_v[e] = dv
                out_p[e] = dp
                out_cov[e] = 0.5 * (cov + cov.T)
                out_J[0, e] = J_R_bg
                out_J[1, e] = J_v_bg
                out_J[2, e] = J_v_ba
                out_J[3, e] = J_p_bg
                out_J[4, e] = J_p_ba
    return out_R, out_v, out_p, out_cov, out_J[0], out_J[1], out_J[2], out_J[3], out_J[4]


@njit(cache=True, nogil=True)
def _rk4_rhs(R: np.ndarray, v: np.ndarray, w: np.ndarray, a: np.ndarray, g_vec: np.ndarray):
    return R @ nb_skew(w), R @ a + g_vec, v


@njit(cache=True, nogil=True)
def nb_integrate_state_rk4(t_s: np.ndarray, gyro: np.ndarray, accel: np.ndarray, R0: np.ndarray,
                           p0: np.ndarray, v0: np.ndarray, g_vec: np.ndarray):
    """RK4 of dR/dt = R [w]x, dv/dt = R a + g, dp/dt = v with linearly interpolated (bias-free) inputs.

    R is projected back onto SO(3) after every step. Returns R (M, 3, 3), p (M, 3), v (M, 3) at the
    M sample times (the first being the initial state).
    """
    m = t_s.shape[0]
    Rs = np.empty((m, 3, 3))
    ps = np.empty((m, 3))
    vs = np.empty((m, 3))
    R = R0.copy()
    p = p0.copy()
    v = v0.copy()
    Rs[0] = R
    ps[0] = p
    vs[0] = v
    for k in range(m - 1):
        h = t_s[k + 1] - t_s[k]
        w_mid = 0.5 * (gyro[k] + gyro[k + 1])
        a_mid = 0.5 * (accel[k] + accel[k + 1])
        dR1, dv1, dp1 = _rk4_rhs(R, v, gyro[k], accel[k], g_vec)
        dR2, dv2, dp2 = _rk4_rhs(R + 0.5 * h * dR1, v + 0.5 * h * dv1, w_mid, a_mid, g_vec)
        dR3, dv3, dp3 = _rk4_rhs(R + 0.5 * h * dR2, v + 0.5 * h * dv2, w_mid, a_mid, g_vec)
        dR4, dv4, dp4 = _rk4_rhs(R + h * dR3, v + h * dv3, gyro[k + 1], accel[k + 1], g_vec)
        R = nb_normalize_rotation(R + (h / 6.0) * (dR1 + 2.0 * dR2 + 2.0 * dR3 + dR4))
        v = v + (h / 6.0) * (dv1 + 2.0 * dv2 + 2.0 * dv3 + dv4)
        p = p + (h / 6.0) * (dp1 + 2.0 * dp2 + 2.0 * dp3 + dp4)
        Rs[k + 1] = R
        ps[k + 1] = p
        vs[k + 1] = v
    return Rs, ps, vs
