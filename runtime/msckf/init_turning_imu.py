"""A turning IMU that stands still: its orientations from the gyro, its gravity and accelerometer bias."""
from __future__ import annotations

import numpy as np

from runtime.geometry.so3 import so3_exp
from runtime.msckf.init_dynamic_linear import min_quadratic_on_sphere


def gyro_orientations(t_ns: np.ndarray, gyro: np.ndarray, bg: np.ndarray,
                      t_query_ns: np.ndarray) -> np.ndarray:
    """R_{I(t0) I(t)} (k, 3, 3) at t_query_ns from the bias-corrected gyro (t_ns (n,), gyro (n, 3) rad/s).

    Midpoint rates between samples; a query between two samples takes the partial step, one before the
    first or after the last sample extrapolates the first or last rate."""
    w = 0.5 * (gyro[1:] + gyro[:-1]) - bg
    dt = np.diff(t_ns) * 1e-9
    steps = so3_exp(w * dt[:, None])                     # all increments at once
    R = np.empty((t_ns.shape[0], 3, 3))
    R[0] = np.eye(3)
    for k in range(dt.shape[0]):
        R[k + 1] = R[k] @ steps[k]
    t_query_ns = np.asarray(t_query_ns, dtype=np.int64)
    k = np.clip(np.searchsorted(t_ns, t_query_ns, side="right") - 1, 0, dt.shape[0] - 1)
    partial = so3_exp(w[k] * ((t_query_ns - t_ns[k]) * 1e-9)[:, None])
    return R[k] @ partial


def gravity_and_accel_bias(R_0k: np.ndarray, accel: np.ndarray,
                           g0: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Gravity and accelerometer bias of a standing IMU whose orientation turned by R_{I0 Ik} (n, 3, 3).

    Each sample reads f_k = R_ek^T up_e + ba, with up_e the specific force of gravity (|up_e| = g0) in
    the newest sample's frame e and R_ek = R_0e^T R_0k. ba enters linearly: for a given up_e it is
    mean_k R_ek^T (R_ek f_k - up_e) in closed form, leaving a quadratic in up_e minimised on the
    sphere |up_e| = g0. Along the turn axis of a turn about one axis the design has no information:
    there the components the turn determines are solved alone and the axis component fills |up_e| = g0
    on the mean specific force's side (for a turn about gravity that leaves the bias along it as the
    static initializer sets it). Of the two sphere points a nearly one-axis turn leaves nearly equal,
    the one on the mean specific force's side along the weakest direction is taken.

    Returns up_e (3,) m/s^2 in I(e), ba (3,) m/s^2 in I, and the turn's spread: the RMS angle (rad)
    by which the bias direction turns, sqrt(second-smallest eigenvalue of the design / n).
    """
    n = R_0k.shape[0]
    R_ek = np.einsum("ji,kjl->kil", R_0k[-1], R_0k)
    f = np.einsum("kij,kj->ki", R_ek, accel)              # specific force rotated into I(e)
    R_bar = np.transpose(R_ek, (0, 2, 1)).mean(axis=0)    # mean_k R_ek^T
    c = accel.mean(axis=0)                               # mean_k R_ek^T f_k = the raw mean
    d = f - np.einsum("kij,j->ki", R_ek, c)
    B = np.eye(3)[None] - np.einsum("kij,jl->kil", R_ek, R_bar)
    M = np.einsum("kji,kjl->il", B, B)
    m = np.einsum("kji,kj->i", B, d)
    f_mean = f.mean(axis=0)
    e, U = np.linalg.eigh(M)
    informed = e > 1e-9 * max(float(e[-1]), 0.0) if e[-1] > 0.0 else np.zeros(3, dtype=bool)
    if informed.all():
        up = min_quadratic_on_sphere(M, m, g0)
        u0 = U[:, 0]
        if (up @ u0) * (f_mean @ u0) < 0.0:              # the mirror point along the weakest direction
            up = up - 2.0 * (up @ u0) * u0
    else:                                                # the turn leaves 1 (or, not turning, 3) free
        p = U[:, informed] @ ((U[:, informed].T @ m) / e[informed])
        if np.linalg.norm(p) > g0:
            p *= g0 / np.linalg.norm(p)
        free = U[:, ~informed]
        q = free @ (free.T @ f_mean)
        q = q / np.linalg.norm(q) if np.linalg.norm(q) > 0.0 else free[:, 0]
        up = p + np.sqrt(max(g0 * g0 - float(p @ p), 0.0)) * q
    ba = c - R_bar @ up
    return up, ba, float(np.sqrt(max(e[1], 0.0) / n))
