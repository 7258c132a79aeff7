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


@njit(cache=True, nogil=True)
def _to_camera(R: np.ndarray, p: np.ndarray, p_O: np.ndarray, R_IC: np.ndarray, p_IC: np.ndarray,
               pI: np.ndarray, pC: np.ndarray) -> None:
    """pI = R^T (p_O - p), pC = R_IC^T (pI - p_IC), written into pI and pC (scalar loops)."""
    d0, d1, d2 = p_O[0] - p[0], p_O[1] - p[1], p_O[2] - p[2]
    for k in range(3):
        pI[k] = R[0, k] * d0 + R[1, k] * d1 + R[2, k] * d2
    e0, e1, e2 = pI[0] - p_IC[0], pI[1] - p_IC[1], pI[2] - p_IC[2]
    for k in range(3):
        pC[k] = R_IC[0, k] * e0 + R_IC[1, k] * e1 + R_IC[2, k] * e2


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
    # scalar 3-vector and 2x3 products: numba sends every small `@` to BLAS, which dominated this kernel
    pI = np.empty(3)
    pC = np.empty(3)
    Jz = np.empty((2, 3))
    A = np.empty((2, 3))
    for i in range(m):
        _to_camera(Rc[i], pc[i], p_O, R_IC, p_IC, pI, pC)
        if pC[2] <= 1e-6:
            return False, r, Hc, He, Hf
        u, v, _ = distort_point(code, prm, pC[0] / pC[2], pC[1] / pC[2])
        r[2 * i] = uv[i, 0] - u
        r[2 * i + 1] = uv[i, 1] - v
        _to_camera(Rf[i], pf[i], p_O_fej, R_IC, p_IC, pI, pC)
        if pC[2] <= 1e-6:
            return False, r, Hc, He, Hf
        iz = 1.0 / pC[2]
        x = pC[0] * iz
        y = pC[1] * iz
        _, _, Jd = distort_point(code, prm, x, y)
        R = Rf[i]
        for a in range(2):
            # Jz = Jd [[1/z, 0, -x/z], [0, 1/z, -y/z]] (d z / d p_C); A = Jz R_IC^T
            Jz[a, 0] = Jd[a, 0] * iz
            Jz[a, 1] = Jd[a, 1] * iz
            Jz[a, 2] = -(Jd[a, 0] * x + Jd[a, 1] * y) * iz
            for k in range(3):
                A[a, k] = Jz[a, 0] * R_IC[k, 0] + Jz[a, 1] * R_IC[k, 1] + Jz[a, 2] * R_IC[k, 2]
            row = 2 * i + a
            # A [pI]x and Jz [pC]x (columns of M [v]x: M1 v2 - M2 v1, M2 v0 - M0 v2, M0 v1 - M1 v0)
            Hc[row, 0] = A[a, 1] * pI[2] - A[a, 2] * pI[1]
            Hc[row, 1] = A[a, 2] * pI[0] - A[a, 0] * pI[2]
            Hc[row, 2] = A[a, 0] * pI[1] - A[a, 1] * pI[0]
            He[row, 0] = Jz[a, 1] * pC[2] - Jz[a, 2] * pC[1]
            He[row, 1] = Jz[a, 2] * pC[0] - Jz[a, 0] * pC[2]
            He[row, 2] = Jz[a, 0] * pC[1] - Jz[a, 1] * pC[0]
            for k in range(3):
                b = A[a, 0] * R[k, 0] + A[a, 1] * R[k, 1] + A[a, 2] * R[k, 2]     # (A R_f^T)[a, k]
                Hc[row, 3 + k] = -b
                Hf[row, k] = b
                He[row, 3 + k] = -A[a, k]
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


@njit(cache=True, nogil=True)
def spd_mahalanobis(S: np.ndarray, r: np.ndarray) -> float:
    """r^T S^-1 r by a Cholesky factorisation of the symmetric S (inf when S is not positive definite)."""
    n = S.shape[0]
    L = np.zeros((n, n))
    for j in range(n):
        d = S[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 0.0:
            return np.inf
        L[j, j] = np.sqrt(d)
        for i in range(j + 1, n):
            s = S[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
    y = np.empty(n)
    q = 0.0
    for i in range(n):
        s = r[i]
        for k in range(i):
            s -= L[i, k] * y[k]
        y[i] = s / L[i, i]
        q += y[i] * y[i]
    return q


@njit(cache=True, nogil=True)
def projected_mahalanobis(Pcc: np.ndarray, H: np.ndarray, r: np.ndarray, sigma: float) -> float:
    """r^T (H Pcc H^T + sigma^2 I)^-1 r (inf when that is not positive definite)."""
    S = H @ Pcc @ H.T
    for i in range(S.shape[0]):
        S[i, i] += sigma * sigma
    return spd_mahalanobis(S, r)
