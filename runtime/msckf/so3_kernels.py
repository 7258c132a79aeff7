"""Scalar SO(3) kernels (numba) used inside the filter's jitted loops.

Exp(phi) = expm([phi]x); Jr(phi) the right Jacobian, Jl(phi) = Jr(-phi) the left one.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def skew3(v: np.ndarray) -> np.ndarray:
    """[v]x, so that skew3(a) @ b = a x b."""
    S = np.zeros((3, 3))
    S[0, 1] = -v[2]
    S[0, 2] = v[1]
    S[1, 0] = v[2]
    S[1, 2] = -v[0]
    S[2, 0] = -v[1]
    S[2, 1] = v[0]
    return S


@njit(cache=True, nogil=True)
def exp3(phi: np.ndarray) -> np.ndarray:
    """Exp(phi) for a (3,) rotation vector (rad)."""
    th2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2]
    K = skew3(phi)
    if th2 < 1e-12:
        return np.eye(3) + K + 0.5 * (K @ K)
    th = np.sqrt(th2)
    return np.eye(3) + (np.sin(th) / th) * K + ((1.0 - np.cos(th)) / th2) * (K @ K)


@njit(cache=True, nogil=True)
def log3(R: np.ndarray) -> np.ndarray:
    """Log(R) as a (3,) rotation vector (rad)."""
    c = 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0)
    c = min(1.0, max(-1.0, c))
    th = np.arccos(c)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if th < 1e-6:
        return 0.5 * w
    if th > np.pi - 1e-4:
        # near pi: axis from the symmetric part
        B = 0.5 * (R + R.T) - c * np.eye(3)
        k = 0
        if B[1, 1] > B[k, k]:
            k = 1
        if B[2, 2] > B[k, k]:
            k = 2
        a = B[:, k] / np.sqrt(max(B[k, k], 1e-300))
        a = a / np.linalg.norm(a)
        if a[0] * w[0] + a[1] * w[1] + a[2] * w[2] < 0:
            a = -a
        return th * a
    return (th / (2.0 * np.sin(th))) * w


@njit(cache=True, nogil=True)
def jr3(phi: np.ndarray) -> np.ndarray:
    """Right Jacobian of SO(3): Exp(phi + d) ~ Exp(phi) Exp(Jr(phi) d)."""
    th2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2]
    K = skew3(phi)
    if th2 < 1e-10:
        return np.eye(3) - 0.5 * K + (K @ K) / 6.0
    th = np.sqrt(th2)
    return np.eye(3) - ((1.0 - np.cos(th)) / th2) * K + ((th - np.sin(th)) / (th2 * th)) * (K @ K)


@njit(cache=True, nogil=True)
def jl3(phi: np.ndarray) -> np.ndarray:
    """Left Jacobian of SO(3), Jl(phi) = Jr(-phi)."""
    return jr3(-phi)


@njit(cache=True, nogil=True)
def quat_to_rot(q: np.ndarray) -> np.ndarray:
    """Hamilton quaternion (w, x, y, z), normalised inside, to a rotation matrix."""
    n = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    w, x, y, z = q[0] / n, q[1] / n, q[2] / n, q[3] / n
    R = np.empty((3, 3))
    R[0, 0] = 1 - 2 * (y * y + z * z)
    R[0, 1] = 2 * (x * y - w * z)
    R[0, 2] = 2 * (x * z + w * y)
    R[1, 0] = 2 * (x * y + w * z)
    R[1, 1] = 1 - 2 * (x * x + z * z)
    R[1, 2] = 2 * (y * z - w * x)
    R[2, 0] = 2 * (x * z - w * y)
    R[2, 1] = 2 * (y * z + w * x)
    R[2, 2] = 1 - 2 * (x * x + y * y)
    return R


@njit(cache=True, nogil=True)
def rot_to_quat(R: np.ndarray) -> np.ndarray:
    """Rotation matrix to a Hamilton quaternion (w, x, y, z) with w >= 0."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    q = np.empty(4)
    if tr > 0:
        s = np.sqrt(tr + 1.0) * 2
        q[0] = 0.25 * s
        q[1] = (R[2, 1] - R[1, 2]) / s
        q[2] = (R[0, 2] - R[2, 0]) / s
        q[3] = (R[1, 0] - R[0, 1]) / s
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2]) * 2
        q[0] = (R[2, 1] - R[1, 2]) / s
        q[1] = 0.25 * s
        q[2] = (R[0, 1] + R[1, 0]) / s
        q[3] = (R[0, 2] + R[2, 0]) / s
    elif R[1, 1] > R[2, 2]:
        s = np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2]) * 2
        q[0] = (R[0, 2] - R[2, 0]) / s
        q[1] = (R[0, 1] + R[1, 0]) / s
        q[2] = 0.25 * s
        q[3] = (R[1, 2] + R[2, 1]) / s
    else:
        s = np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1]) * 2
        q[0] = (R[1, 0] - R[0, 1]) / s
        q[1] = (R[0, 2] + R[2, 0]) / s
        q[2] = (R[1, 2] + R[2, 1]) / s
        q[3] = 0.25 * s
    if q[0] < 0:
        q = -q
    return q / np.sqrt(q @ q)


@njit(cache=True, nogil=True)
def normalize_rot(R: np.ndarray) -> np.ndarray:
    """The nearest rotation (via a quaternion round trip)."""
    return quat_to_rot(rot_to_quat(R))
