"""Scalar SO(3) kernels (numba) used inside the filter's jitted loops.

The rotation kernels are runtime.geometry's (one implementation, tested against scipy and finite
differences), under the short names the filter's code uses: Exp(phi) = expm([phi]x); Jr(phi) the
right Jacobian, Jl(phi) = Jr(-phi) the left one. The quaternion kernels (Hamilton, w first) serve
the RK4 propagation.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from runtime.geometry.kernels import nb_left_jacobian as jl3
from runtime.geometry.kernels import nb_right_jacobian as jr3
from runtime.geometry.kernels import nb_skew as skew3
from runtime.geometry.kernels import nb_so3_exp as exp3
from runtime.geometry.kernels import nb_so3_log as log3

__all__ = ["exp3", "jl3", "jr3", "log3", "normalize_rot", "quat_to_rot", "rot_to_quat", "skew3"]


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
