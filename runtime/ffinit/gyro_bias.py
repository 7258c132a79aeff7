"""Gyroscope-bias change from aligning DA3 relative rotations with preintegrated ones (Sec. IV-B).

DA3 predicts R_C0Ci; through the extrinsics this is an IMU rotation R_I0Ii^DA3 = R_IC R_C0Ci R_CI.
The preintegrated rotation at bias bg + dbg is R_I0Ii Exp(J_R_bg,i dbg) (first order), so dbg
minimises sum_i rho(|Log((R_I0Ii Exp(J_i dbg))^T R_I0Ii^DA3)|) (Gauss–Newton, iteratively reweighted;
rho is quadratic, or Huber on the per-image residual norm when a threshold is given).
"""
from __future__ import annotations

import numpy as np

from runtime.ffinit.window import InitWindow
from runtime.geometry import so3_exp, so3_left_jacobian_inv, so3_log


def rotation_residuals(window: InitWindow, dbg: np.ndarray) -> np.ndarray:
    """(N-1, 3) residuals Log(R_pre(dbg)^T R_da3) of images 1..N-1, radians."""
    R_CI = window.R_IC.T
    out = []
    for i in range(1, window.num_images):
        R_da3 = window.R_IC @ window.images[i].R_C0Ci @ R_CI
        R_pre = window.R_I0Ii[i] @ so3_exp(window.J_R_bg[i] @ dbg)
        out.append(so3_log(R_pre.T @ R_da3))
    return np.asarray(out).reshape(-1, 3)


def align_gyro_bias(window: InitWindow, iterations: int = 3, huber_rad: float | None = None) -> np.ndarray:
    """The gyro-bias change dbg (rad/s) that best aligns preintegrated and DA3 rotations.

    huber_rad: Huber threshold on each image's residual norm (rad); None = least squares. With a
    threshold, up to 3 further reweighting iterations are run.
    """
    dbg = np.zeros(3)
    for _ in range(iterations + (3 if huber_rad else 0)):
        r = rotation_residuals(window, dbg)
        rows, rhs = [], []
        for k, i in enumerate(range(1, window.num_images)):
            # Log(Exp(-J d) Exp(r)) ~= r - Jl^-1(r) J d; Huber weight sqrt(min(1, delta / |r|))
            norm = float(np.linalg.norm(r[k]))
            w = np.sqrt(min(1.0, huber_rad / norm)) if huber_rad and norm > 0 else 1.0
            rows.append(w * so3_left_jacobian_inv(r[k]) @ window.J_R_bg[i])
            rhs.append(w * r[k])
        A = np.concatenate(rows)
        b = np.concatenate(rhs)
        if np.linalg.matrix_rank(A) < 3:
            return dbg
        step, *_ = np.linalg.lstsq(A, b, rcond=None)
        dbg = dbg + step
        if np.linalg.norm(step) < 1e-10:
            break
    return dbg
