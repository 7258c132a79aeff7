"""Visual measurement model (numba): distorted-pixel residuals, Jacobians, nullspace projection.

A point p_O seen from clone (R_OI, p_OI) with extrinsics (R_IC, p_IC):
    p_C = R_IC^T (R_OI^T (p_O - p_OI) - p_IC),   z = distort(p_C / p_C.z).
Error states: clone [dtheta (right), dp], extrinsics [dphi (right on R_IC), dp_IC], point dp_O, and
(online intrinsics calibration) the additive intrinsics [fx, fy, cx, cy, d0..d3].
Jacobians are evaluated at the clones' first estimates (FEJ) and the given point.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from runtime.msckf.camera_kernels import distort_jacobian_params, distort_point
from runtime.msckf.so3_kernels import skew3


@njit(cache=True, nogil=True)
def feature_jacobians(Rc: np.ndarray, pc: np.ndarray, Rf: np.ndarray, pf: np.ndarray, uv: np.ndarray,
                      p_O: np.ndarray, p_O_fej: np.ndarray, R_IC: np.ndarray, p_IC: np.ndarray, code: int,
                      prm: np.ndarray) -> tuple:
    """Residuals and Jacobians of one point over m observations.

    Rc, pc: current clone poses (m,3,3), (m,3); Rf, pf: their first estimates; uv (m,2) measured pixels;
    p_O: the point for the residual, p_O_fej: the point for the Jacobians.
    Returns ok, r (2m,), Hc (2m, 6) (row pair i belongs to clone i), He (2m, 6) extrinsics, Hf (2m, 3).
    """
    m = uv.shape[0]
    r = np.zeros(2 * m)
    Hc = np.zeros((2 * m, 6))
    He = np.zeros((2 * m, 6))
    Hf = np.zeros((2 * m, 3))
    RCI = R_IC.T
    for i in range(m):
        pI = Rc[i].T @ (p_O - pc[i])
        pC = RCI @ (pI - p_IC)
        if pC[2] <= 1e-6:
            return False, r, Hc, He, Hf
        u, v, _ = distort_point(code, prm, pC[0] / pC[2], pC[1] / pC[2])
        r[2 * i] = uv[i, 0] - u
        r[2 * i + 1] = uv[i, 1] - v
        pIf = Rf[i].T @ (p_O_fej - pf[i])
        pCf = RCI @ (pIf - p_IC)
        if pCf[2] <= 1e-6:
            return False, r, Hc, He, Hf
        x = pCf[0] / pCf[2]
        y = pCf[1] / pCf[2]
        _, _, Jd = distort_point(code, prm, x, y)
        Jp = np.array([[1.0 / pCf[2], 0.0, -x / pCf[2]], [0.0, 1.0 / pCf[2], -y / pCf[2]]])
        Jz = Jd @ Jp  # d z / d p_C
        A = Jz @ RCI
        Hc[2 * i:2 * i + 2, 0:3] = A @ skew3(pIf)
        Hc[2 * i:2 * i + 2, 3:6] = -A @ Rf[i].T
        He[2 * i:2 * i + 2, 0:3] = Jz @ skew3(pCf)
        He[2 * i:2 * i + 2, 3:6] = -A
        Hf[2 * i:2 * i + 2, :] = A @ Rf[i].T
    return True, r, Hc, He, Hf


@njit(cache=True, nogil=True)
def feature_intrinsics_jacobian(Rf: np.ndarray, pf: np.ndarray, p_O_fej: np.ndarray, R_IC: np.ndarray,
                                p_IC: np.ndarray, code: int, prm: np.ndarray) -> np.ndarray:
    """(2m, 8) Jacobian of the m distorted pixels of a point w.r.t. the intrinsics prm[:8], at the same
    linearisation point as `feature_jacobians` (clones Rf, pf; point p_O_fej). Rows of observations
    behind the camera are zero (feature_jacobians rejects those tracks)."""
    m = Rf.shape[0]
    Hk = np.zeros((2 * m, 8))
    RCI = R_IC.T
    for i in range(m):
        pCf = RCI @ (Rf[i].T @ (p_O_fej - pf[i]) - p_IC)
        if pCf[2] <= 1e-6:
            continue
        Hk[2 * i:2 * i + 2, :] = distort_jacobian_params(code, prm, pCf[0] / pCf[2], pCf[1] / pCf[2])
    return Hk


@njit(cache=True, nogil=True)
def givens_left_nullspace(Hf: np.ndarray, Hx: np.ndarray, r: np.ndarray) -> tuple:
    """Project (Hx, r) onto the left nullspace of Hf (M, k) with Givens rotations (in place).

    Returns the projected (Hx (M-k, n), r (M-k,)); the projection is orthonormal, so isotropic noise
    stays isotropic. Also returns the rotated Hf's top (k, k) block and the top rows of Hx and r
    (the part that carries the feature), used by delayed landmark initialisation.
    """
    M, k = Hf.shape
    n = Hx.shape[1]
    for j in range(k):
        for i in range(M - 1, j, -1):
            a = Hf[i - 1, j]
            b = Hf[i, j]
            if b == 0.0:
                continue
            rr = np.hypot(a, b)
            c = a / rr
            s = b / rr
            for col in range(j, k):
                t0 = Hf[i - 1, col]
                t1 = Hf[i, col]
                Hf[i - 1, col] = c * t0 + s * t1
                Hf[i, col] = -s * t0 + c * t1
            for col in range(n):
                t0 = Hx[i - 1, col]
                t1 = Hx[i, col]
                Hx[i - 1, col] = c * t0 + s * t1
                Hx[i, col] = -s * t0 + c * t1
            t0 = r[i - 1]
            t1 = r[i]
            r[i - 1] = c * t0 + s * t1
            r[i] = -s * t0 + c * t1
    return Hx[k:].copy(), r[k:].copy(), Hf[:k].copy(), Hx[:k].copy(), r[:k].copy()
