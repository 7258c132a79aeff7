"""numba hot loops of IMU preintegration and state propagation (see preintegration.py for the maths)."""
from __future__ import annotations

import numpy as np
from numba import njit

from runtime.geometry.kernels import (
    nb_matmul3_into,
    nb_normalize_rotation,
    nb_right_jacobian_into,
    nb_skew,
    nb_so3_exp_into,
)


@njit(cache=True, nogil=True)
def nb_preintegrate(dts: np.ndarray, gyro: np.ndarray, accel: np.ndarray, bg: np.ndarray, ba: np.ndarray,
                    var_g: float, var_a: float, with_cov: bool, end_nodes: np.ndarray):
    """Preintegrate K intervals between K+1 nodes (midpoint scheme, see Preintegration).

    dts (K,) s; gyro, accel (K+1, 3) node measurements; bg, ba (3,) biases; var_g, var_a the squared
    continuous noise densities; end_nodes (E,) the node indices at which to report (node 0 = start).
    Returns, stacked over the E ends: dR (E,3,3), dv (E,3), dp (E,3), cov (E,9,9, order [phi, v, p]),
    J_R_bg, J_v_bg, J_v_ba, J_p_bg, J_p_ba (E,3,3). The loop allocates nothing.
    """
    n_end = end_nodes.shape[0]
    out_R = np.zeros((n_end, 3, 3))
    out_v = np.zeros((n_end, 3))
    out_p = np.zeros((n_end, 3))
    out_cov = np.zeros((n_end, 9, 9))
    out_J = np.zeros((5, n_end, 3, 3))
    dR = np.eye(3)
    dv = np.zeros(3)
    dp = np.zeros(3)
    J_R_bg = np.zeros((3, 3))
    J_v_bg = np.zeros((3, 3))
    J_v_ba = np.zeros((3, 3))
    J_p_bg = np.zeros((3, 3))
    J_p_ba = np.zeros((3, 3))
    cov = np.zeros((9, 9))
    # work buffers
    dR_k = np.empty((3, 3))
    H = np.empty((3, 3))
    Jr = np.empty((3, 3))
    Jr_half = np.empty((3, 3))
    R_half = np.empty((3, 3))
    Ra = np.empty((3, 3))
    J_half = np.empty((3, 3))
    RaJ = np.empty((3, 3))
    M = np.empty((3, 3))
    G = np.empty((3, 3))
    tmp = np.empty((3, 3))
    A = np.zeros((9, 3))
    B = np.zeros((9, 6))
    AP = np.empty((9, 9))
    acc = np.empty(3)
    for e in range(n_end):
        if end_nodes[e] == 0:
            out_R[e] = dR
    for k in range(dts.shape[0]):
        dt = dts[k]
        hdt2 = 0.5 * dt * dt
        w0 = 0.5 * (gyro[k, 0] + gyro[k + 1, 0]) - bg[0]
        w1 = 0.5 * (gyro[k, 1] + gyro[k + 1, 1]) - bg[1]
        w2 = 0.5 * (gyro[k, 2] + gyro[k + 1, 2]) - bg[2]
        a0 = 0.5 * (accel[k, 0] + accel[k + 1, 0]) - ba[0]
        a1 = 0.5 * (accel[k, 1] + accel[k + 1, 1]) - ba[1]
        a2 = 0.5 * (accel[k, 2] + accel[k + 1, 2]) - ba[2]
        nb_so3_exp_into(w0 * dt, w1 * dt, w2 * dt, dR_k)
        nb_so3_exp_into(0.5 * w0 * dt, 0.5 * w1 * dt, 0.5 * w2 * dt, H)
        nb_right_jacobian_into(w0 * dt, w1 * dt, w2 * dt, Jr)
        nb_right_jacobian_into(0.5 * w0 * dt, 0.5 * w1 * dt, 0.5 * w2 * dt, Jr_half)
        nb_matmul3_into(dR, H, R_half)
        for i in range(3):
            r0, r1, r2 = R_half[i, 0], R_half[i, 1], R_half[i, 2]
            # row i of R_half [a]x is (row i of R_half) x a
            Ra[i, 0] = r1 * a2 - r2 * a1
            Ra[i, 1] = r2 * a0 - r0 * a2
            Ra[i, 2] = r0 * a1 - r1 * a0
            acc[i] = r0 * a0 + r1 * a1 + r2 * a2
        # bias Jacobians: derivatives of this discrete scheme, from the values before the step
        nb_matmul3_into(H, J_R_bg, J_half, True)
        for i in range(3):
            for j in range(3):
                J_half[i, j] -= 0.5 * dt * Jr_half[i, j]
        nb_matmul3_into(Ra, J_half, RaJ)
        nb_matmul3_into(dR_k, J_R_bg, tmp, True)
        for i in range(3):
            for j in range(3):
                J_p_bg[i, j] += dt * J_v_bg[i, j] - hdt2 * RaJ[i, j]
                J_p_ba[i, j] += dt * J_v_ba[i, j] - hdt2 * R_half[i, j]
                J_v_bg[i, j] -= dt * RaJ[i, j]
                J_v_ba[i, j] -= dt * R_half[i, j]
                J_R_bg[i, j] = tmp[i, j] - dt * Jr[i, j]
        if with_cov:
            # M = Ra H^T, G = Ra Jr_half
            for i in range(3):
                for j in range(3):
                    sm = 0.0
                    sg = 0.0
                    for m in range(3):
                        sm += Ra[i, m] * H[j, m]
                        sg += Ra[i, m] * Jr_half[m, j]
                    M[i, j] = sm
                    G[i, j] = sg
            sq_g = np.sqrt(var_g / dt)
            sq_a = np.sqrt(var_a / dt)
            for i in range(3):
                for j in range(3):
                    A[i, j] = dR_k[j, i]
                    A[3 + i, j] = -dt * M[i, j]
                    A[6 + i, j] = -hdt2 * M[i, j]
                    B[i, j] = sq_g * dt * Jr[i, j]
                    B[3 + i, j] = -sq_g * hdt2 * G[i, j]
                    B[6 + i, j] = -sq_g * 0.25 * dt * dt * dt * G[i, j]
                    B[3 + i, 3 + j] = sq_a * dt * R_half[i, j]
                    B[6 + i, 3 + j] = sq_a * hdt2 * R_half[i, j]
            # cov = A cov A^T + B B^T with A = [[D, 0, 0], [Mv, I, 0], [Mp, dt I, I]]: only A's
            # first three columns (the (9, 3) array A) are general
            for i in range(9):
                for j in range(9):
                    s = A[i, 0] * cov[0, j] + A[i, 1] * cov[1, j] + A[i, 2] * cov[2, j]
                    if i >= 3:
                        s += cov[i, j]
                    if i >= 6:
                        s += dt * cov[i - 3, j]
                    AP[i, j] = s
            for i in range(9):
                for j in range(i, 9):
                    s = AP[i, 0] * A[j, 0] + AP[i, 1] * A[j, 1] + AP[i, 2] * A[j, 2]
                    if j >= 3:
                        s += AP[i, j]
                    if j >= 6:
                        s += dt * AP[i, j - 3]
                    for m in range(6):
                        s += B[i, m] * B[j, m]
                    cov[i, j] = s
                    cov[j, i] = s
        for i in range(3):
            dp[i] += dt * dv[i] + hdt2 * acc[i]
            dv[i] += dt * acc[i]
        nb_matmul3_into(dR, dR_k, tmp)
        dR[:, :] = tmp
        for e in range(n_end):
            if end_nodes[e] == k + 1:
                out_R[e] = nb_normalize_rotation(dR)
                out_v[e] = dv
                out_p[e] = dp
                out_cov[e] = cov
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
