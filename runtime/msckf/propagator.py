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

from runtime.msckf.so3_kernels import jl3, jr3, quat_to_rot, rot_to_quat, skew3


@njit(cache=True, nogil=True)
def _qmul_omega(q: np.ndarray, w: np.ndarray) -> np.ndarray:
    """0.5 * q (x) [0, w] for a Hamilton quaternion q (w, x, y, z)."""
    out = np.empty(4)
    out[0] = 0.5 * (-q[1] * w[0] - q[2] * w[1] - q[3] * w[2])
    out[1] = 0.5 * (q[0] * w[0] + q[2] * w[2] - q[3] * w[1])
    out[2] = 0.5 * (q[0] * w[1] + q[3] * w[0] - q[1] * w[2])
    out[3] = 0.5 * (q[0] * w[2] + q[1] * w[1] - q[2] * w[0])
    return out


@njit(cache=True, nogil=True)
def rk4_step(R: np.ndarray, p: np.ndarray, v: np.ndarray, w0: np.ndarray, w1: np.ndarray,
             a0: np.ndarray, a1: np.ndarray, g: np.ndarray, dt: float) -> tuple:
    """One RK4 step of (R_OI, p, v) with bias-corrected body rates/specific forces linear in time."""
    q = rot_to_quat(R)
    wm = 0.5 * (w0 + w1)
    am = 0.5 * (a0 + a1)
    k1q = _qmul_omega(q, w0)
    k1v = quat_to_rot(q) @ a0 + g
    k1p = v.copy()
    q2 = q + 0.5 * dt * k1q
    v2 = v + 0.5 * dt * k1v
    k2q = _qmul_omega(q2, wm)
    k2v = quat_to_rot(q2) @ am + g
    k2p = v2
    q3 = q + 0.5 * dt * k2q
    v3 = v + 0.5 * dt * k2v
    k3q = _qmul_omega(q3, wm)
    k3v = quat_to_rot(q3) @ am + g
    k3p = v3
    q4 = q + dt * k3q
    v4 = v + dt * k3v
    k4q = _qmul_omega(q4, w1)
    k4v = quat_to_rot(q4) @ a1 + g
    k4p = v4
    qn = q + dt / 6.0 * (k1q + 2 * k2q + 2 * k3q + k4q)
    qn = qn / np.sqrt(qn @ qn)
    vn = v + dt / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)
    pn = p + dt / 6.0 * (k1p + 2 * k2p + 2 * k3p + k4p)
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
        phi = wm * dt
        Jr = jr3(phi)
        Jl = jl3(phi)
        Ak = skew3(am)
        F = np.eye(15)
        F[0:3, 0:3] = R1.T @ Rk
        F[0:3, 9:12] = -Jr * dt
        F[3:6, 0:3] = -skew3(p1 - pk - vk * dt - 0.5 * g * dt * dt) @ Rk
        F[3:6, 6:9] = np.eye(3) * dt
        F[3:6, 9:12] = Rk @ Ak * (dt * dt * dt / 6.0)
        F[3:6, 12:15] = -0.5 * Rk * dt * dt
        F[6:9, 0:3] = -skew3(v1 - vk - g * dt) @ Rk
        F[6:9, 9:12] = Rk @ Ak * (0.5 * dt * dt)
        F[6:9, 12:15] = -Rk @ Jl * dt
        G = np.zeros((15, 12))
        G[0:3, 0:3] = -Jr * dt
        G[3:6, 3:6] = -0.5 * Rk * dt * dt
        G[6:9, 0:3] = Rk @ Ak * (0.5 * dt * dt)
        G[6:9, 3:6] = -Rk @ Jl * dt
        G[9:12, 6:9] = np.eye(3) * dt
        G[12:15, 9:12] = np.eye(3) * dt
        qc = np.empty(12)
        qc[0:3] = sig_g * sig_g / dt
        qc[3:6] = sig_a * sig_a / dt
        qc[6:9] = sig_wg * sig_wg / dt
        qc[9:12] = sig_wa * sig_wa / dt
        Gq = G * qc
        Q = F @ Q @ F.T + Gq @ G.T
        Phi = F @ Phi
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
