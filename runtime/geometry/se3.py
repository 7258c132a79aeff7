"""The rigid-motion group SE(3) as 4x4 homogeneous matrices T_AB (maps B-coordinates to A).

Tangent vectors are xi = [rho, phi] (translation part first, then rotation, both (..., 3));
Exp(xi) = [[Exp(phi), Jl(phi) rho], [0, 1]] (Jl is the SO(3) left Jacobian, often called V).
"""
from __future__ import annotations

import numpy as np

from runtime.geometry.checks import as_matrices, as_vectors
from runtime.geometry.so3 import so3_exp, so3_left_jacobian, so3_left_jacobian_inv, so3_log


def make_pose(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Homogeneous (..., 4, 4) poses from rotations (..., 3, 3) and translations (..., 3) (broadcast)."""
    R = as_matrices(R, "R")
    p = as_vectors(p, "p")
    lead = np.broadcast_shapes(R.shape[:-2], p.shape[:-1])
    T = np.zeros(lead + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = p
    T[..., 3, 3] = 1.0
    return T


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """Poses Exp(xi) of (..., 6) twists xi = [rho (m), phi (rad)]; (..., 4, 4)."""
    xi = as_vectors(xi, "xi", 6)
    rho, phi = xi[..., :3], xi[..., 3:]
    t = np.einsum("...ij,...j->...i", so3_left_jacobian(phi), rho)
    return make_pose(so3_exp(phi), t)


def se3_log(T: np.ndarray) -> np.ndarray:
    """Twists [rho, phi] = Log(T) of (..., 4, 4) poses (|phi| <= pi); (..., 6)."""
    T = as_matrices(T, "T", 4)
    phi = so3_log(T[..., :3, :3])
    rho = np.einsum("...ij,...j->...i", so3_left_jacobian_inv(phi), T[..., :3, 3])
    return np.concatenate([rho, phi], axis=-1)


def se3_inverse(T: np.ndarray) -> np.ndarray:
    """Inverse poses T_BA of (..., 4, 4) poses T_AB, using the rotation transpose; (..., 4, 4)."""
    T = as_matrices(T, "T", 4)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return make_pose(Rt, -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3]))


def yaw_translation_fit(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(R, t, strength): the rotation about z and translation minimising sum |dst_k - (R src_k + t)|^2
    over (K,3) point pairs, in closed form.

    With centred points x (src) and y (dst), sum y^T Rz x = cos(yaw) a + sin(yaw) b where
    a = sum(x0 y0 + x1 y1) and b = sum(x0 y1 - x1 y0), so yaw = atan2(b, a) and t = mean(y) - Rz mean(x);
    strength = hypot(a, b) (m^2), 0 when the yaw is unobservable (no horizontal extent).
    """
    from runtime.geometry.so3 import rot_z

    src = np.asarray(src, np.float64).reshape(-1, 3)
    dst = np.asarray(dst, np.float64).reshape(-1, 3)
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    xs, xd = src - mu_s, dst - mu_d
    a = float(np.sum(xs[:, 0] * xd[:, 0] + xs[:, 1] * xd[:, 1]))
    b = float(np.sum(xs[:, 0] * xd[:, 1] - xs[:, 1] * xd[:, 0]))
    R = rot_z(np.arctan2(b, a))
    return R, mu_d - R @ mu_s, float(np.hypot(a, b))
