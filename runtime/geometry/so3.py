"""The rotation group SO(3): hat/vee, exponential and logarithm maps, Jacobians, projection.

Conventions: Exp(phi) = expm(skew(phi)); the right Jacobian satisfies
Exp(phi + dphi) ~= Exp(phi) Exp(Jr(phi) dphi) and the left one Jl(phi) = Jr(-phi), so that
Exp(phi + dphi) ~= Exp(Jl(phi) dphi) Exp(phi). Every function accepts one element ((3,) or (3, 3))
or a stack over leading axes ((..., 3) or (..., 3, 3)); angles are in radians.
The coefficient functions switch to Taylor series near zero so that no 0/0 or cancellation occurs.
"""
from __future__ import annotations

import numpy as np

from runtime.geometry.checks import GeometryError, as_matrices, as_vectors

_SMALL = 1e-8       # below this angle sin(t)/t and friends are evaluated by their series
_SERIES = 0.25      # below this angle the cancelling coefficients use their series


def skew(v: np.ndarray) -> np.ndarray:
    """The cross-product matrix [v]x of (..., 3) vectors, so that skew(a) @ b = a x b; (..., 3, 3)."""
    v = as_vectors(v, "v")
    out = np.zeros(v.shape + (3,))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def vee(S: np.ndarray) -> np.ndarray:
    """The vector of a (..., 3, 3) skew-symmetric matrix (its antisymmetric part is used); (..., 3)."""
    S = as_matrices(S, "S")
    return 0.5 * np.stack([S[..., 2, 1] - S[..., 1, 2], S[..., 0, 2] - S[..., 2, 0],
                           S[..., 1, 0] - S[..., 0, 1]], axis=-1)


def _coeffs_exp(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A = sin(t)/t and B = (1 - cos t)/t^2, free of cancellation."""
    small = theta < _SMALL
    t = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(t) / t)
    half = np.sin(0.5 * t) / t
    b = np.where(small, 0.5 - theta**2 / 24.0, 2.0 * half * half)
    return a, b


def _coeff_c(theta: np.ndarray) -> np.ndarray:
    """C = (t - sin t)/t^3 (series below 0.25 rad)."""
    series = theta < _SERIES
    t = np.where(series, 1.0, theta)
    t2 = theta * theta
    ser = 1.0 / 6.0 - t2 / 120.0 + t2**2 / 5040.0 - t2**3 / 362880.0 + t2**4 / 39916800.0
    return np.where(series, ser, (t - np.sin(t)) / t**3)


def _coeff_d(theta: np.ndarray) -> np.ndarray:
    """D = 1/t^2 - (1 + cos t)/(2 t sin t) (series below 0.25 rad; singular at 2 pi)."""
    series = theta < _SERIES
    t = np.where(series, 1.0, theta)
    t2 = theta * theta
    ser = 1.0 / 12.0 + t2 / 720.0 + t2**2 / 30240.0 + t2**3 / 1209600.0 + t2**4 / 47900160.0
    with np.errstate(divide="ignore", invalid="ignore"):
        direct = 1.0 / t**2 - np.cos(0.5 * t) / (2.0 * t * np.sin(0.5 * t))
    return np.where(series, ser, direct)


def so3_exp(phi: np.ndarray) -> np.ndarray:
    """Rotation matrices Exp(phi) of (..., 3) rotation vectors (rad); (..., 3, 3)."""
    phi = as_vectors(phi, "phi")
    theta = np.linalg.norm(phi, axis=-1)
    a, b = _coeffs_exp(theta)
    K = skew(phi)
    return np.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K)


def kabsch_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation R (3, 3) minimising sum |b_i - R a_i|^2 over paired vectors a, b (n, 3) (Kabsch; a
    proper rotation, det +1, also for coplanar or collinear points); for stacks (..., n, 3) of pairs,
    one rotation per stack element (..., 3, 3)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    U, _, Vt = np.linalg.svd(np.swapaxes(a, -1, -2) @ b)
    V, Ut = np.swapaxes(Vt, -1, -2), np.swapaxes(U, -1, -2)
    flip = np.ones(V.shape[:-2] + (1, 3))
    flip[..., 0, 2] = np.where(np.linalg.det(V @ Ut) >= 0.0, 1.0, -1.0)
    return (V * flip) @ Ut


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vectors Log(R) (rad, norm in [0, pi]) of (..., 3, 3) rotations; (..., 3).

    The angle comes from atan2(|w|, (tr R - 1)/2) with w = vee(R - R^T)/2. Below pi/2 the axis is
    w/|w|; above it the axis is read from the symmetric part (R + R^T)/2 = c I + (1 - c) a a^T,
    which stays accurate up to and at pi (where the sign of the axis is arbitrary).
    """
    R_in = as_matrices(R, "R")
    R = R_in.reshape(-1, 3, 3)
    w = vee(R)
    s = np.linalg.norm(w, axis=-1)
    c = 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0)
    theta = np.arctan2(s, c)
    # small and moderate angles: theta / sin(theta) * w
    small = s < _SMALL
    with np.errstate(divide="ignore", invalid="ignore"):
        series = 1.0 + theta**2 / 6.0 + 7.0 * theta**4 / 360.0
        ratio = np.where(small, series, theta / np.where(small, 1.0, s))
    out = ratio[..., None] * w
    big = c < 0.0
    if np.any(big):
        Rb, cb, wb, tb = R[big], c[big], w[big], theta[big]
        S = 0.5 * (Rb + np.swapaxes(Rb, -1, -2))
        aat = (S - cb[:, None, None] * np.eye(3)) / (1.0 - cb)[:, None, None]
        diag = np.diagonal(aat, axis1=-2, axis2=-1)
        k = np.argmax(diag, axis=-1)
        col = np.take_along_axis(aat, k[:, None, None], axis=-1)[..., 0]
        axis = col / np.linalg.norm(col, axis=-1, keepdims=True)
        sign = np.where(np.einsum("ni,ni->n", axis, wb) < 0.0, -1.0, 1.0)
        out[big] = (sign * tb)[:, None] * axis
    return out.reshape(R_in.shape[:-1])


def so3_right_jacobian(phi: np.ndarray) -> np.ndarray:
    """Right Jacobian Jr(phi) = I - B [phi]x + C [phi]x^2 of (..., 3) rotation vectors; (..., 3, 3)."""
    phi = as_vectors(phi, "phi")
    theta = np.linalg.norm(phi, axis=-1)
    _, b = _coeffs_exp(theta)
    c = _coeff_c(theta)
    K = skew(phi)
    return np.eye(3) - b[..., None, None] * K + c[..., None, None] * (K @ K)


def so3_left_jacobian(phi: np.ndarray) -> np.ndarray:
    """Left Jacobian Jl(phi) = Jr(-phi) = I + B [phi]x + C [phi]x^2; (..., 3, 3)."""
    return so3_right_jacobian(-as_vectors(phi, "phi"))


def so3_right_jacobian_inv(phi: np.ndarray) -> np.ndarray:
    """Inverse right Jacobian I + [phi]x/2 + D [phi]x^2 (valid for |phi| < 2 pi); (..., 3, 3)."""
    phi = as_vectors(phi, "phi")
    theta = np.linalg.norm(phi, axis=-1)
    if np.any(theta >= 2.0 * np.pi - 1e-6):
        raise GeometryError("so3_right_jacobian_inv is singular at |phi| = 2 pi; pass a vector from so3_log")
    d = _coeff_d(theta)
    K = skew(phi)
    return np.eye(3) + 0.5 * K + d[..., None, None] * (K @ K)


def so3_left_jacobian_inv(phi: np.ndarray) -> np.ndarray:
    """Inverse left Jacobian Jl(phi)^-1 = Jr(-phi)^-1; (..., 3, 3)."""
    return so3_right_jacobian_inv(-as_vectors(phi, "phi"))


def normalize_rotation(R: np.ndarray) -> np.ndarray:
    """The rotation matrix nearest (Frobenius) to each (..., 3, 3) matrix, via SVD (det = +1)."""
    R = as_matrices(R, "R")
    if not np.all(np.isfinite(R)):
        raise GeometryError("normalize_rotation got a non-finite matrix")
    U, _, Vt = np.linalg.svd(R)
    d = np.sign(np.linalg.det(U @ Vt))
    d = np.where(d == 0.0, 1.0, d)
    U = U.copy()
    U[..., :, 2] *= d[..., None]
    return U @ Vt


def so3_interpolate(R0: np.ndarray, R1: np.ndarray, alpha: np.ndarray | float) -> np.ndarray:
    """Geodesic interpolation R0 Exp(alpha Log(R0^T R1)); alpha = 0 gives R0, 1 gives R1.

    R0, R1 (..., 3, 3) and alpha (...) broadcast against each other; alpha outside [0, 1]
    extrapolates along the same geodesic.
    """
    R0 = as_matrices(R0, "R0")
    R1 = as_matrices(R1, "R1")
    alpha = np.asarray(alpha, dtype=np.float64)
    delta = so3_log(np.swapaxes(R0, -1, -2) @ R1)
    return R0 @ so3_exp(alpha[..., None] * delta)


def rot_z(yaw: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations about z by yaw (rad); the third row and column are exactly (0, 0, 1)."""
    yaw = np.asarray(yaw, np.float64)
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.zeros(yaw.shape + (3, 3))
    out[..., 0, 0] = c
    out[..., 0, 1] = -s
    out[..., 1, 0] = s
    out[..., 1, 1] = c
    out[..., 2, 2] = 1.0
    return out
