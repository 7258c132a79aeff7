"""Strap-down integration of IMU samples from a known state (for checks and the drift benchmark).

Between samples k and k+1 (dt): R_{k+1} = R_k Exp(((w_k + w_{k+1})/2 - bg) dt); the world
accelerations a_k = R_k (f_k - ba) - (0, 0, g) are taken as linear in time, so
v_{k+1} = v_k + dt (a_k + a_{k+1}) / 2 and p_{k+1} = p_k + dt v_k + dt^2 (2 a_k + a_{k+1}) / 6.
"""

from __future__ import annotations

import numpy as np

from drivers.sim.motion import G0
from runtime.geometry.so3 import so3_exp


def integrate_imu(
    t_ns: np.ndarray,
    gyro: np.ndarray,
    accel: np.ndarray,
    R0: np.ndarray,
    p0: np.ndarray,
    v0: np.ndarray,
    bg: np.ndarray | None = None,
    ba: np.ndarray | None = None,
    g: float = G0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """States (R (N,3,3), p (N,3), v (N,3)) at every sample, starting from (R0, p0, v0) at t_ns[0].

    bg, ba: constant biases (3,) or per-sample (N,3); None = zero.
    """
    t_ns = np.asarray(t_ns, np.int64)
    n = t_ns.size
    bg = np.zeros((n, 3)) if bg is None else np.broadcast_to(np.asarray(bg, float), (n, 3))
    ba = np.zeros((n, 3)) if ba is None else np.broadcast_to(np.asarray(ba, float), (n, 3))
    w = np.asarray(gyro, float) - bg
    f = np.asarray(accel, float) - ba
    dt = np.diff(t_ns).astype(np.float64) * 1e-9
    R = np.empty((n, 3, 3))
    p = np.empty((n, 3))
    v = np.empty((n, 3))
    R[0], p[0], v[0] = R0, p0, v0
    gv = np.array([0.0, 0.0, g])
    dR = so3_exp(0.5 * (w[:-1] + w[1:]) * dt[:, None])
    a_prev = R[0] @ f[0] - gv
    for k in range(n - 1):
        R[k + 1] = R[k] @ dR[k]
        a_next = R[k + 1] @ f[k + 1] - gv
        h = dt[k]
        v[k + 1] = v[k] + h * 0.5 * (a_prev + a_next)
        p[k + 1] = p[k] + h * v[k] + h * h * (2.0 * a_prev + a_next) / 6.0
        a_prev = a_next
    return R, p, v
