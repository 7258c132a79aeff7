"""Quaternion <-> rotation-matrix conversions, used only at file boundaries.

Hamilton quaternions (EuRoC: w,x,y,z; TUM / scipy: x,y,z,w) give
R = (2w^2 - 1) I + 2w [v]x + 2 v v^T, the rotation that the quaternion product q p q* applies.
JPL quaternions (OpenVINS stores q_GtoI as x,y,z,w) give R_GtoI = (2w^2 - 1) I - 2w [v]x + 2 v v^T,
so a JPL quaternion of R equals the Hamilton quaternion of R^T.
Inputs are normalised; outputs are unit quaternions with w >= 0. Vectorised over leading axes.
"""
from __future__ import annotations

import numpy as np

from runtime.geometry.checks import GeometryError, as_matrices, as_vectors


def _unit(q: np.ndarray, name: str) -> np.ndarray:
    q = as_vectors(q, name, 4)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if not np.all(np.isfinite(n)) or np.any(n < 1e-12):
        raise GeometryError(f"{name} holds a zero or non-finite quaternion")
    return q / n


def quat_wxyz_to_rot(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of Hamilton quaternions (..., 4) ordered w, x, y, z."""
    q = _unit(q, "q_wxyz")
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1.0 - 2.0 * (y * y + z * z)
    R[..., 0, 1] = 2.0 * (x * y - w * z)
    R[..., 0, 2] = 2.0 * (x * z + w * y)
    R[..., 1, 0] = 2.0 * (x * y + w * z)
    R[..., 1, 1] = 1.0 - 2.0 * (x * x + z * z)
    R[..., 1, 2] = 2.0 * (y * z - w * x)
    R[..., 2, 0] = 2.0 * (x * z - w * y)
    R[..., 2, 1] = 2.0 * (y * z + w * x)
    R[..., 2, 2] = 1.0 - 2.0 * (x * x + y * y)
    return R


def rot_to_quat_wxyz(R: np.ndarray) -> np.ndarray:
    """Hamilton quaternions w, x, y, z (w >= 0) of (..., 3, 3) rotation matrices; (..., 4).

    Shepperd's method: the quaternion is computed from the largest of 1 + tr R and 1 + 2 R_ii - tr R,
    which keeps it accurate for every angle.
    """
    R = as_matrices(R, "R")
    flat = R.reshape(-1, 3, 3)
    tr = np.trace(flat, axis1=-2, axis2=-1)
    d = np.diagonal(flat, axis1=-2, axis2=-1)
    cand = np.stack([1.0 + tr, 1.0 + 2.0 * d[:, 0] - tr, 1.0 + 2.0 * d[:, 1] - tr, 1.0 + 2.0 * d[:, 2] - tr],
                    axis=-1)
    k = np.argmax(cand, axis=-1)
    r21, r12 = flat[:, 2, 1], flat[:, 1, 2]
    r02, r20 = flat[:, 0, 2], flat[:, 2, 0]
    r10, r01 = flat[:, 1, 0], flat[:, 0, 1]
    # 4 * q_k * q for each choice of the large component k (rows: w, x, y, z)
    opts = np.stack([
        np.stack([cand[:, 0], r21 - r12, r02 - r20, r10 - r01], axis=-1),
        np.stack([r21 - r12, cand[:, 1], r01 + r10, r02 + r20], axis=-1),
        np.stack([r02 - r20, r01 + r10, cand[:, 2], r12 + r21], axis=-1),
        np.stack([r10 - r01, r02 + r20, r12 + r21, cand[:, 3]], axis=-1),
    ], axis=1)
    q = opts[np.arange(flat.shape[0]), k]
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    q *= np.where(q[:, 0] < 0.0, -1.0, 1.0)[:, None]
    return q.reshape(R.shape[:-2] + (4,))


def quat_xyzw_to_rot(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of Hamilton quaternions ordered x, y, z, w (TUM, scipy default)."""
    q = as_vectors(q, "q_xyzw", 4)
    return quat_wxyz_to_rot(np.roll(q, 1, axis=-1))


def rot_to_quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Hamilton quaternions x, y, z, w (w >= 0) of rotation matrices."""
    return np.roll(rot_to_quat_wxyz(R), -1, axis=-1)


def jpl_xyzw_to_rot(q: np.ndarray) -> np.ndarray:
    """R_GtoI of OpenVINS JPL quaternions q_GtoI stored x, y, z, w; (..., 3, 3)."""
    return np.swapaxes(quat_xyzw_to_rot(q), -1, -2)


def rot_to_jpl_xyzw(R_GtoI: np.ndarray) -> np.ndarray:
    """OpenVINS JPL quaternions q_GtoI (x, y, z, w, with w >= 0) of rotations R_GtoI; (..., 4)."""
    R_GtoI = as_matrices(R_GtoI, "R_GtoI")
    return rot_to_quat_xyzw(np.swapaxes(R_GtoI, -1, -2))
