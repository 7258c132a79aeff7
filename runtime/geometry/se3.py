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
