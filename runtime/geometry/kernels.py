"""numba-jitted scalar SO(3) kernels for the filter's and the preintegrator's hot loops.

Same conventions and formulas as runtime.geometry.so3 (tested to agree with it); each function
takes one (3,) vector or one (3, 3) matrix of float64 and returns a new array.
Compiled with @njit(cache=True, nogil=True) so they are callable from other numba code.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

_SMALL = 1e-8
_SERIES = 0.25


@njit(cache=True, nogil=True)
def nb_skew(v: np.ndarray) -> np.ndarray:
    """[v]x, the cross-product matrix of a (3,) vector."""
    S = np.zeros((3, 3))
    S[0, 1] = -v[2]
    S[0, 2] = v[1]
    S[1, 0] = v[2]
    S[1, 2] = -v[0]
    S[2, 0] = -v[1]
    S[2, 1] = v[0]
    return S


@njit(cache=True, nogil=True)
def nb_exp_coeffs(theta: float) -> tuple[float, float]:
    """A = sin(t)/t, B = (1 - cos t)/t^2 without cancellation."""
    if theta < _SMALL:
        return 1.0 - theta * theta / 6.0, 0.5 - theta * theta / 24.0
    h = math.sin(0.5 * theta) / theta
    return math.sin(theta) / theta, 2.0 * h * h


@njit(cache=True, nogil=True)
def nb_coeff_c(theta: float) -> float:
    """C = (t - sin t)/t^3."""
    if theta < _SERIES:
        t2 = theta * theta
        return 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0 - t2**3 / 362880.0 + t2**4 / 39916800.0
    return (theta - math.sin(theta)) / theta**3


@njit(cache=True, nogil=True)
def nb_coeff_d(theta: float) -> float:
    """D = 1/t^2 - (1 + cos t)/(2 t sin t)."""
    if theta < _SERIES:
        t2 = theta * theta
        return 1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0 + t2**3 / 1209600.0 + t2**4 / 47900160.0
    return 1.0 / (theta * theta) - math.cos(0.5 * theta) / (2.0 * theta * math.sin(0.5 * theta))


@njit(cache=True, nogil=True)
def nb_so3_exp(phi: np.ndarray) -> np.ndarray:
    """Exp(phi) of a (3,) rotation vector (rad); (3, 3)."""
    theta = math.sqrt(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2])
    a, b = nb_exp_coeffs(theta)
    K = nb_skew(phi)
    return np.eye(3) + a * K + b * (K @ K)


@njit(cache=True, nogil=True)
def nb_so3_log(R: np.ndarray) -> np.ndarray:
    """Log(R) of a (3, 3) rotation, norm in [0, pi] (robust at pi); (3,)."""
    w = np.empty(3)
    w[0] = 0.5 * (R[2, 1] - R[1, 2])
    w[1] = 0.5 * (R[0, 2] - R[2, 0])
    w[2] = 0.5 * (R[1, 0] - R[0, 1])
    s = math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    c = 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0)
    theta = math.atan2(s, c)
    if c >= 0.0:
        if s < _SMALL:
            return (1.0 + theta * theta / 6.0 + 7.0 * theta**4 / 360.0) * w
        return (theta / s) * w
    k = 0
    best = -1e300
    for i in range(3):
        d = (R[i, i] - c) / (1.0 - c)
        if d > best:
            best = d
            k = i
    axis = np.empty(3)
    for i in range(3):
        axis[i] = (0.5 * (R[i, k] + R[k, i]) - (c if i == k else 0.0)) / (1.0 - c)
    n = math.sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2])
    sign = 1.0 if axis[0] * w[0] + axis[1] * w[1] + axis[2] * w[2] >= 0.0 else -1.0
    return (sign * theta / n) * axis


@njit(cache=True, nogil=True)
def nb_right_jacobian(phi: np.ndarray) -> np.ndarray:
    """Jr(phi) with Exp(phi + dphi) ~= Exp(phi) Exp(Jr dphi); (3, 3)."""
    theta = math.sqrt(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2])
    _, b = nb_exp_coeffs(theta)
    c = nb_coeff_c(theta)
    K = nb_skew(phi)
    return np.eye(3) - b * K + c * (K @ K)


@njit(cache=True, nogil=True)
def nb_right_jacobian_inv(phi: np.ndarray) -> np.ndarray:
    """Jr(phi)^-1 (valid for |phi| < 2 pi); (3, 3)."""
    theta = math.sqrt(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2])
    d = nb_coeff_d(theta)
    K = nb_skew(phi)
    return np.eye(3) + 0.5 * K + d * (K @ K)


@njit(cache=True, nogil=True)
def nb_left_jacobian(phi: np.ndarray) -> np.ndarray:
    """Jl(phi) = Jr(-phi); (3, 3)."""
    return nb_right_jacobian(-phi)


@njit(cache=True, nogil=True)
def nb_left_jacobian_inv(phi: np.ndarray) -> np.ndarray:
    """Jl(phi)^-1 = Jr(-phi)^-1; (3, 3)."""
    return nb_right_jacobian_inv(-phi)


@njit(cache=True, nogil=True)
def nb_normalize_rotation(R: np.ndarray) -> np.ndarray:
    """Nearest rotation matrix (SVD projection with det = +1); (3, 3)."""
    U, _, Vt = np.linalg.svd(R)
    M = U @ Vt
    if np.linalg.det(M) < 0.0:
        for i in range(3):
            U[i, 2] = -U[i, 2]
        M = U @ Vt
    return M


@njit(cache=True, nogil=True)
def nb_so3_exp_into(phi0: float, phi1: float, phi2: float, out: np.ndarray) -> None:
    """Writes Exp([phi0, phi1, phi2]) into the (3, 3) array `out` (no allocation)."""
    theta = math.sqrt(phi0 * phi0 + phi1 * phi1 + phi2 * phi2)
    a, b = nb_exp_coeffs(theta)
    _rodrigues_into(phi0, phi1, phi2, 1.0, a, b, out)


@njit(cache=True, nogil=True)
def nb_right_jacobian_into(phi0: float, phi1: float, phi2: float, out: np.ndarray) -> None:
    """Writes Jr([phi0, phi1, phi2]) = I - B [phi]x + C [phi]x^2 into `out` (no allocation)."""
    theta = math.sqrt(phi0 * phi0 + phi1 * phi1 + phi2 * phi2)
    _, b = nb_exp_coeffs(theta)
    _rodrigues_into(phi0, phi1, phi2, 1.0, -b, nb_coeff_c(theta), out)


@njit(cache=True, nogil=True)
def _rodrigues_into(x: float, y: float, z: float, i_coef: float, k_coef: float, k2_coef: float,
                    out: np.ndarray) -> None:
    """out = i_coef I + k_coef [p]x + k2_coef [p]x^2 for p = (x, y, z); [p]x^2 = p p^T - |p|^2 I."""
    n2 = x * x + y * y + z * z
    d = i_coef - k2_coef * n2
    out[0, 0] = d + k2_coef * x * x
    out[1, 1] = d + k2_coef * y * y
    out[2, 2] = d + k2_coef * z * z
    out[0, 1] = k2_coef * x * y - k_coef * z
    out[1, 0] = k2_coef * x * y + k_coef * z
    out[0, 2] = k2_coef * x * z + k_coef * y
    out[2, 0] = k2_coef * x * z - k_coef * y
    out[1, 2] = k2_coef * y * z - k_coef * x
    out[2, 1] = k2_coef * y * z + k_coef * x


@njit(cache=True, nogil=True)
def nb_matmul3_into(A: np.ndarray, B: np.ndarray, out: np.ndarray, transpose_a: bool = False) -> None:
    """out = A B (or A^T B when transpose_a) for (3, 3) arrays; `out` must not alias A or B."""
    for i in range(3):
        for j in range(3):
            s = 0.0
            for k in range(3):
                s += (A[k, i] if transpose_a else A[i, k]) * B[k, j]
            out[i, j] = s
