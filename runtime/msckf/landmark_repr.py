"""Anchored inverse-depth landmarks (OpenVINS ANCHORED_MSCKF_INVERSE_DEPTH), as numba kernels.

A landmark is lam = [alpha, beta, rho] = [x/z, y/z, 1/z] of its position p_A = (x, y, z) in the anchor
camera, the camera of one clone (R_OI, p_OI) with extrinsics (R_IC, p_IC):
    p_O = R_OI (R_IC p_A + p_IC) + p_OI.
Error states: lam additive, clone [dtheta (right), dp], extrinsics [dphi (right on R_IC), dp_IC].
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def lam_to_anchor_point(lam: np.ndarray) -> np.ndarray:
    """[alpha, beta, rho] -> p_A."""
    return np.array([lam[0] / lam[2], lam[1] / lam[2], 1.0 / lam[2]])


@njit(cache=True, nogil=True)
def anchor_point_to_lam(p: np.ndarray) -> np.ndarray:
    """p_A -> [x/z, y/z, 1/z]."""
    return np.array([p[0] / p[2], p[1] / p[2], 1.0 / p[2]])


@njit(cache=True, nogil=True)
def d_lam_d_point(p: np.ndarray) -> np.ndarray:
    """d lam / d p_A at p_A."""
    z = p[2]
    z2 = z * z
    return np.array([[1.0 / z, 0.0, -p[0] / z2], [0.0, 1.0 / z, -p[1] / z2], [0.0, 0.0, -1.0 / z2]])


@njit(cache=True, nogil=True)
def _mul3(A: np.ndarray, B: np.ndarray, out: np.ndarray, sign: float) -> None:
    """out = sign A B for 3x3 A, B (scalar loops: numba sends every small `@` to BLAS)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = sign * (A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j])


@njit(cache=True, nogil=True)
def _mul_skew3(X: np.ndarray, v: np.ndarray, out: np.ndarray, col: int, sign: float) -> None:
    """out[:, col:col+3] = sign X [v]x for 3x3 X (columns of X [v]x: X1 v2 - X2 v1, X2 v0 - X0 v2,
    X0 v1 - X1 v0)."""
    for i in range(3):
        out[i, col] = sign * (X[i, 1] * v[2] - X[i, 2] * v[1])
        out[i, col + 1] = sign * (X[i, 2] * v[0] - X[i, 0] * v[2])
        out[i, col + 2] = sign * (X[i, 0] * v[1] - X[i, 1] * v[0])


@njit(cache=True, nogil=True)
def anchored_to_global(lam: np.ndarray, R_A: np.ndarray, p_A: np.ndarray, R_IC: np.ndarray,
                       p_IC: np.ndarray) -> tuple:
    """p_O and its Jacobians: d p_O / d lam (3,3), d / d anchor clone (3,6), d / d extrinsics (3,6).

    p_O = R_A q + p_A with q = R_IC p_a + p_IC (the point in the anchor IMU frame); d p_O / d lam =
    R_A R_IC d p_a / d lam; anchor [-R_A [q]x, I]; extrinsics [-R_A R_IC [p_a]x, R_A]."""
    rho = lam[2]
    pa = np.empty(3)
    pa[0] = lam[0] / rho
    pa[1] = lam[1] / rho
    pa[2] = 1.0 / rho
    q = np.empty(3)
    p_O = np.empty(3)
    for i in range(3):
        q[i] = R_IC[i, 0] * pa[0] + R_IC[i, 1] * pa[1] + R_IC[i, 2] * pa[2] + p_IC[i]
    for i in range(3):
        p_O[i] = R_A[i, 0] * q[0] + R_A[i, 1] * q[1] + R_A[i, 2] * q[2] + p_A[i]
    M = np.empty((3, 3))
    _mul3(R_A, R_IC, M, 1.0)
    # d p_a / d lam = [[1/rho, 0, -alpha/rho^2], [0, 1/rho, -beta/rho^2], [0, 0, -1/rho^2]]
    ir = 1.0 / rho
    ir2 = ir * ir
    J_lam = np.empty((3, 3))
    for i in range(3):
        J_lam[i, 0] = M[i, 0] * ir
        J_lam[i, 1] = M[i, 1] * ir
        J_lam[i, 2] = -(M[i, 0] * lam[0] + M[i, 1] * lam[1] + M[i, 2]) * ir2
    J_anchor = np.zeros((3, 6))
    _mul_skew3(R_A, q, J_anchor, 0, -1.0)
    J_ext = np.empty((3, 6))
    _mul_skew3(M, pa, J_ext, 0, -1.0)
    for i in range(3):
        J_anchor[i, 3 + i] = 1.0
        for j in range(3):
            J_ext[i, 3 + j] = R_A[i, j]
    return p_O, J_lam, J_anchor, J_ext


@njit(cache=True, nogil=True)
def global_to_anchored(p_O: np.ndarray, R_A: np.ndarray, p_A: np.ndarray, R_IC: np.ndarray,
                       p_IC: np.ndarray) -> tuple:
    """lam of p_O in the anchor camera, and its Jacobians: d lam / d p_O (3,3), d / d anchor clone (3,6),
    d / d extrinsics (3,6).

    q = R_A^T (p_O - p_A), p_a = R_IC^T (q - p_IC), D = d lam / d p_a, A = R_IC^T R_A^T: d lam / d p_O =
    D A; anchor [D R_IC^T [q]x, -D A]; extrinsics [D [p_a]x, -D R_IC^T]."""
    d = np.empty(3)
    q = np.empty(3)
    pa = np.empty(3)
    for i in range(3):
        d[i] = p_O[i] - p_A[i]
    for i in range(3):
        q[i] = R_A[0, i] * d[0] + R_A[1, i] * d[1] + R_A[2, i] * d[2]
    for i in range(3):
        pa[i] = R_IC[0, i] * (q[0] - p_IC[0]) + R_IC[1, i] * (q[1] - p_IC[1]) + R_IC[2, i] * (q[2] - p_IC[2])
    z = pa[2]
    iz = 1.0 / z
    iz2 = iz * iz
    D = np.zeros((3, 3))    # d lam / d p_a = [[1/z, 0, -x/z^2], [0, 1/z, -y/z^2], [0, 0, -1/z^2]]
    D[0, 0] = iz
    D[1, 1] = iz
    D[0, 2] = -pa[0] * iz2
    D[1, 2] = -pa[1] * iz2
    D[2, 2] = -iz2
    DR = np.empty((3, 3))   # D R_IC^T
    for i in range(3):
        for j in range(3):
            DR[i, j] = D[i, 0] * R_IC[j, 0] + D[i, 1] * R_IC[j, 1] + D[i, 2] * R_IC[j, 2]
    J_p = np.empty((3, 3))
    J_anchor = np.empty((3, 6))
    J_ext = np.empty((3, 6))
    for i in range(3):
        for j in range(3):
            v = DR[i, 0] * R_A[j, 0] + DR[i, 1] * R_A[j, 1] + DR[i, 2] * R_A[j, 2]   # (D R_IC^T R_A^T)[i, j]
            J_p[i, j] = v
            J_anchor[i, 3 + j] = -v
            J_ext[i, 3 + j] = -DR[i, j]
    _mul_skew3(DR, q, J_anchor, 0, 1.0)
    _mul_skew3(D, pa, J_ext, 0, 1.0)
    lam = np.empty(3)
    lam[0] = pa[0] * iz
    lam[1] = pa[1] * iz
    lam[2] = iz
    return lam, J_p, J_anchor, J_ext
