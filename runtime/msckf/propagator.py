"""IMU propagation: RK4 mean, analytic state-transition (Phi) and discrete noise (Qd) per frame.

Error state of the IMU (15): [dtheta (right perturbation of R_OI: R = R_hat Exp(dtheta)), dp, dv, dbg, dba].
Inputs between two samples are linearly interpolated for the RK4 mean; Phi and Qd of each sample interval
are analytic (inputs held at their mean over the interval) and accumulated over the frame. With FEJ, the
columns of Phi that multiply dtheta are re-evaluated at the first estimates of the frame's start state
(OpenVINS: F uses the FEJ at k and the prediction at k+1).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from runtime.geometry.kernels import nb_right_jacobian_into
from runtime.msckf.so3_kernels import quat_to_rot, rot_to_quat, skew3


@njit(cache=True, nogil=True)
def _mm3_into(A: np.ndarray, B: np.ndarray, out: np.ndarray) -> None:
    """out = A B (3x3)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]


@njit(cache=True, nogil=True)
def _mtm3_into(A: np.ndarray, B: np.ndarray, out: np.ndarray) -> None:
    """out = A^T B (3x3)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = A[0, i] * B[0, j] + A[1, i] * B[1, j] + A[2, i] * B[2, j]


@njit(cache=True, nogil=True)
def _skew_mm3_into(x: np.ndarray, B: np.ndarray, out: np.ndarray) -> None:
    """out = [x]x B (3x3)."""
    for j in range(3):
        out[0, j] = -x[2] * B[1, j] + x[1] * B[2, j]
        out[1, j] = x[2] * B[0, j] - x[0] * B[2, j]
        out[2, j] = -x[1] * B[0, j] + x[0] * B[1, j]


@njit(cache=True, nogil=True)
def _mm3_skew_into(A: np.ndarray, x: np.ndarray, out: np.ndarray) -> None:
    """out = A [x]x (3x3)."""
    for i in range(3):
        out[i, 0] = A[i, 1] * x[2] - A[i, 2] * x[1]
        out[i, 1] = A[i, 2] * x[0] - A[i, 0] * x[2]
        out[i, 2] = A[i, 0] * x[1] - A[i, 1] * x[0]


@njit(cache=True, nogil=True)
def _set_block(X: np.ndarray, r: int, c: int, B: np.ndarray, scale: float) -> None:
    """X[r:r+3, c:c+3] = scale B."""
    for i in range(3):
        for j in range(3):
            X[r + i, c + j] = scale * B[i, j]


@njit(cache=True, nogil=True)
def _sparse_left_mul(F: np.ndarray, X: np.ndarray, out: np.ndarray) -> None:
    """out = F X, skipping F's zeros."""
    n, m = F.shape[0], X.shape[1]
    out[:, :] = 0.0
    for i in range(n):
        for k in range(F.shape[1]):
            f = F[i, k]
            if f != 0.0:
                for j in range(m):
                    out[i, j] += f * X[k, j]


@njit(cache=True, nogil=True)
def _sparse_right_mul_t(X: np.ndarray, F: np.ndarray, out: np.ndarray) -> None:
    """out = X F^T, skipping F's zeros."""
    n = X.shape[0]
    out[:, :] = 0.0
    for j in range(F.shape[0]):
        for k in range(F.shape[1]):
            f = F[j, k]
            if f != 0.0:
                for i in range(n):
                    out[i, j] += X[i, k] * f


@njit(cache=True, nogil=True)
def _add_g_qc_gt(G: np.ndarray, qc: np.ndarray, out: np.ndarray) -> None:
    """out += G diag(qc) G^T, skipping G's zeros."""
    n = G.shape[0]
    for c in range(G.shape[1]):
        for i in range(n):
            gi = G[i, c]
            if gi != 0.0:
                s = gi * qc[c]
                for j in range(n):
                    gj = G[j, c]
                    if gj != 0.0:
                        out[i, j] += s * gj


@njit(cache=True, nogil=True)
def _qrot(q0: float, q1: float, q2: float, q3: float, x: np.ndarray) -> tuple:
    """R(q) x for a Hamilton quaternion (w, x, y, z), normalised inside (quat_to_rot's formula, scalars)."""
    n = np.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    w, a, b, c = q0 / n, q1 / n, q2 / n, q3 / n
    r00 = 1 - 2 * (b * b + c * c)
    r01 = 2 * (a * b - w * c)
    r02 = 2 * (a * c + w * b)
    r10 = 2 * (a * b + w * c)
    r11 = 1 - 2 * (a * a + c * c)
    r12 = 2 * (b * c - w * a)
    r20 = 2 * (a * c - w * b)
    r21 = 2 * (b * c + w * a)
    r22 = 1 - 2 * (a * a + b * b)
    return (r00 * x[0] + r01 * x[1] + r02 * x[2], r10 * x[0] + r11 * x[1] + r12 * x[2],
            r20 * x[0] + r21 * x[1] + r22 * x[2])


@njit(cache=True, nogil=True)
def _qdot(q0: float, q1: float, q2: float, q3: float, w: np.ndarray) -> tuple:
    """0.5 * q (x) [0, w] for a Hamilton quaternion q (w, x, y, z), in scalars."""
    return (0.5 * (-q1 * w[0] - q2 * w[1] - q3 * w[2]), 0.5 * (q0 * w[0] + q2 * w[2] - q3 * w[1]),
            0.5 * (q0 * w[1] + q3 * w[0] - q1 * w[2]), 0.5 * (q0 * w[2] + q1 * w[1] - q2 * w[0]))


@njit(cache=True, nogil=True)
def _rk4_slope(q0: float, q1: float, q2: float, q3: float, w: np.ndarray, a: np.ndarray, g: np.ndarray
               ) -> tuple:
    """(dq/dt, dv/dt) at the quaternion q for body rate w and specific force a."""
    f = _qrot(q0, q1, q2, q3, a)
    return _qdot(q0, q1, q2, q3, w), (f[0] + g[0], f[1] + g[1], f[2] + g[2])


@njit(cache=True, nogil=True)
def _rk4_stage(q: np.ndarray, v: np.ndarray, kq: tuple, kv: tuple, step: float, w: np.ndarray,
               a: np.ndarray, g: np.ndarray) -> tuple:
    """The slopes at (q, v) + step * (kq, kv), and that velocity (the position's slope)."""
    qs0, qs1 = q[0] + step * kq[0], q[1] + step * kq[1]
    qs2, qs3 = q[2] + step * kq[2], q[3] + step * kq[3]
    vs = (v[0] + step * kv[0], v[1] + step * kv[1], v[2] + step * kv[2])
    dq, dv = _rk4_slope(qs0, qs1, qs2, qs3, w, a, g)
    return dq, dv, vs


@njit(cache=True, nogil=True)
def rk4_step(R: np.ndarray, p: np.ndarray, v: np.ndarray, w0: np.ndarray, w1: np.ndarray,
             a0: np.ndarray, a1: np.ndarray, g: np.ndarray, dt: float) -> tuple:
    """One RK4 step of (R_OI, p, v) with bias-corrected body rates/specific forces linear in time (the
    quaternion and the 3-vectors in scalars: small numpy temporaries dominated this kernel)."""
    q = rot_to_quat(R)
    wm = 0.5 * (w0 + w1)
    am = 0.5 * (a0 + a1)
    h = 0.5 * dt
    k1q, k1v = _rk4_slope(q[0], q[1], q[2], q[3], w0, a0, g)
    k2q, k2v, v2 = _rk4_stage(q, v, k1q, k1v, h, wm, am, g)        # midpoint predicted by k1
    k3q, k3v, v3 = _rk4_stage(q, v, k2q, k2v, h, wm, am, g)        # midpoint predicted by k2
    k4q, k4v, v4 = _rk4_stage(q, v, k3q, k3v, dt, w1, a1, g)       # end predicted by k3
    c = dt / 6.0
    qn = np.empty(4)
    for i in range(4):
        qn[i] = q[i] + c * (k1q[i] + 2 * k2q[i] + 2 * k3q[i] + k4q[i])
    qn = qn / np.sqrt(qn[0] * qn[0] + qn[1] * qn[1] + qn[2] * qn[2] + qn[3] * qn[3])
    vn = np.empty(3)
    pn = np.empty(3)
    for i in range(3):
        vn[i] = v[i] + c * (k1v[i] + 2 * k2v[i] + 2 * k3v[i] + k4v[i])
        pn[i] = p[i] + c * (v[i] + 2 * v2[i] + 2 * v3[i] + v4[i])
    return quat_to_rot(qn), pn, vn


@njit(cache=True, nogil=True)
def propagate_interval(R: np.ndarray, p: np.ndarray, v: np.ndarray, bg: np.ndarray, ba: np.ndarray,
                       R_fej: np.ndarray, p_fej: np.ndarray, v_fej: np.ndarray, use_fej: bool,
                       t: np.ndarray, w: np.ndarray, a: np.ndarray, g: np.ndarray,
                       sig_g: float, sig_a: float, sig_wg: float, sig_wa: float) -> tuple:
    """Propagate over the samples (t (n,) s, w (n,3), a (n,3)) from t[0] to t[-1].

    Returns R1, p1, v1, Phi (15,15), Qd (15,15), the last bias-corrected body rate (3,).
    """
    Phi = np.eye(15)
    Q = np.zeros((15, 15))
    # per-sample buffers; F and G are sparse (identity plus a few 3x3 blocks): the products below skip their
    # zeros, and the 3x3 blocks are scalar loops (numba sends every small `@` to BLAS)
    F = np.eye(15)
    G = np.zeros((15, 12))
    FX = np.empty((15, 15))
    B = np.empty((3, 3))
    M = np.empty((3, 3))
    Jr = np.empty((3, 3))
    Jl = np.empty((3, 3))
    qc = np.empty(12)
    Rk = R.copy()
    pk = p.copy()
    vk = v.copy()
    w_last = w[t.shape[0] - 1] - bg
    T = 0.0
    for k in range(t.shape[0] - 1):
        dt = t[k + 1] - t[k]
        if dt <= 0.0:
            continue
        T += dt
        w0 = w[k] - bg
        w1 = w[k + 1] - bg
        a0 = a[k] - ba
        a1 = a[k + 1] - ba
        R1, p1, v1 = rk4_step(Rk, pk, vk, w0, w1, a0, a1, g, dt)
        wm = 0.5 * (w0 + w1)
        am = 0.5 * (a0 + a1)
        nb_right_jacobian_into(wm[0] * dt, wm[1] * dt, wm[2] * dt, Jr)
        nb_right_jacobian_into(-wm[0] * dt, -wm[1] * dt, -wm[2] * dt, Jl)       # Jl(phi) = Jr(-phi)
        dt2 = dt * dt
        # F (identity outside the blocks written here)
        _mtm3_into(R1, Rk, B)                                                   # R1^T Rk
        _set_block(F, 0, 0, B, 1.0)
        _set_block(F, 0, 9, Jr, -dt)
        _skew_mm3_into(p1 - pk - vk * dt - 0.5 * g * dt2, Rk, B)               # [.]x Rk
        _set_block(F, 3, 0, B, -1.0)
        for i in range(3):
            F[3 + i, 6 + i] = dt
        _mm3_skew_into(Rk, am, M)                                               # Rk [am]x
        _set_block(F, 3, 9, M, dt2 * dt / 6.0)
        _set_block(F, 3, 12, Rk, -0.5 * dt2)
        _skew_mm3_into(v1 - vk - g * dt, Rk, B)
        _set_block(F, 6, 0, B, -1.0)
        _set_block(F, 6, 9, M, 0.5 * dt2)
        _mm3_into(Rk, Jl, B)                                                    # Rk Jl
        _set_block(F, 6, 12, B, -dt)
        # G (the same zero pattern at every sample)
        _set_block(G, 0, 0, Jr, -dt)
        _set_block(G, 3, 3, Rk, -0.5 * dt2)
        _set_block(G, 6, 0, M, 0.5 * dt2)
        _set_block(G, 6, 3, B, -dt)
        for i in range(3):
            G[9 + i, 6 + i] = dt
            G[12 + i, 9 + i] = dt
        qc[0:3] = sig_g * sig_g / dt
        qc[3:6] = sig_a * sig_a / dt
        qc[6:9] = sig_wg * sig_wg / dt
        qc[9:12] = sig_wa * sig_wa / dt
        # Q <- F Q F^T + G diag(qc) G^T, Phi <- F Phi
        _sparse_left_mul(F, Q, FX)
        _sparse_right_mul_t(FX, F, Q)
        _add_g_qc_gt(G, qc, Q)
        _sparse_left_mul(F, Phi, FX)
        Phi[:, :] = FX
        Rk, pk, vk = R1, p1, v1
    if use_fej:
        Phi[0:3, 0:3] = Rk.T @ R_fej
        Phi[3:6, 0:3] = -skew3(pk - p_fej - v_fej * T - 0.5 * g * T * T) @ R_fej
        Phi[6:9, 0:3] = -skew3(vk - v_fej - g * T) @ R_fej
    Q = 0.5 * (Q + Q.T)
    return Rk, pk, vk, Phi, Q, w_last


def select_samples(t_ns: np.ndarray, w: np.ndarray, a: np.ndarray, t0_ns: int, t1_ns: int
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """IMU samples covering [t0, t1] with linearly interpolated (or held) end points.

    t_ns (n,) int64 sorted; returns t (m,) seconds relative to t0, w (m,3), a (m,3). When t1 lies past the
    newest sample the last sample is held (the caller bounds how far).
    """
    n = t_ns.shape[0]
    if n == 0:
        raise ValueError("no IMU samples")

    def at(tq: int) -> tuple[np.ndarray, np.ndarray]:
        j = int(np.searchsorted(t_ns, tq))
        if j <= 0:
            return w[0], a[0]
        if j >= n:
            return w[n - 1], a[n - 1]
        if t_ns[j] == tq:
            return w[j], a[j]
        al = (tq - t_ns[j - 1]) / float(t_ns[j] - t_ns[j - 1])
        return (1 - al) * w[j - 1] + al * w[j], (1 - al) * a[j - 1] + al * a[j]

    lo = int(np.searchsorted(t_ns, t0_ns, side="right"))
    hi = int(np.searchsorted(t_ns, t1_ns, side="left"))
    w0, a0 = at(t0_ns)
    w1, a1 = at(t1_ns)
    ts = np.concatenate(([t0_ns], t_ns[lo:hi], [t1_ns]))
    ws = np.vstack((w0[None], w[lo:hi], w1[None]))
    as_ = np.vstack((a0[None], a[lo:hi], a1[None]))
    return (ts - t0_ns).astype(np.float64) * 1e-9, ws, as_
