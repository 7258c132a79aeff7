"""Feature triangulation (numba): linear solve in the anchor camera with a conditioning check, then
Levenberg-Marquardt refinement in anchored inverse depth, with depth and baseline checks (OpenVINS
FeatureInitializer logic, our own implementation).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _cost(Rt: np.ndarray, Rtp: np.ndarray, xn: np.ndarray, x0: float, x1: float, x2: float) -> float:
    """Sum of squared normalised-coordinate errors of the anchored inverse-depth point (x0, x1, x2)."""
    c = 0.0
    for i in range(xn.shape[0]):
        R = Rt[i]
        h0 = R[0, 0] * x0 + R[0, 1] * x1 + R[0, 2] - x2 * Rtp[i, 0]
        h1 = R[1, 0] * x0 + R[1, 1] * x1 + R[1, 2] - x2 * Rtp[i, 1]
        h2 = R[2, 0] * x0 + R[2, 1] * x1 + R[2, 2] - x2 * Rtp[i, 2]
        if h2 <= 0:
            return 1e30
        e0 = h0 / h2 - xn[i, 0]
        e1 = h1 / h2 - xn[i, 1]
        c += e0 * e0 + e1 * e1
    return c


@njit(cache=True, nogil=True)
def _solve_spd3(a00: float, a01: float, a02: float, a11: float, a12: float, a22: float, g0: float, g1: float,
                g2: float) -> tuple:
    """(ok, x) with A x = g for the symmetric 3x3 A (upper entries given), by Cholesky in scalars; ok False
    (x zero) when A is not positive definite."""
    if not a00 > 0.0:
        return False, 0.0, 0.0, 0.0
    l00 = np.sqrt(a00)
    l10 = a01 / l00
    l20 = a02 / l00
    d1 = a11 - l10 * l10
    if not d1 > 0.0:
        return False, 0.0, 0.0, 0.0
    l11 = np.sqrt(d1)
    l21 = (a12 - l20 * l10) / l11
    d2 = a22 - l20 * l20 - l21 * l21
    if not d2 > 0.0:
        return False, 0.0, 0.0, 0.0
    l22 = np.sqrt(d2)
    y0 = g0 / l00
    y1 = (g1 - l10 * y0) / l11
    y2 = (g2 - l20 * y0 - l21 * y1) / l22
    x2 = y2 / l22
    x1 = (y1 - l21 * x2) / l11
    x0 = (y0 - l10 * x1 - l20 * x2) / l00
    return True, x0, x1, x2


@njit(cache=True, nogil=True)
def triangulate(
    R_OC: np.ndarray,
    p_OC: np.ndarray,
    xn: np.ndarray,
    max_cond: float,
    min_dist: float,
    max_dist: float,
    max_baseline_ratio: float,
    iterations: int,
) -> tuple:
    """Triangulate one feature seen by m cameras (m >= 2).

    R_OC (m,3,3), p_OC (m,3): camera poses in the world; xn (m,2): normalised (undistorted) image
    coordinates. The anchor is camera 0. Returns (ok, p_O (3,) world point).
    """
    m = xn.shape[0]
    pO = np.zeros(3)
    if m < 2:
        return False, pO
    RA = R_OC[0]
    pA = p_OC[0]
    A = np.zeros((3, 3))
    b = np.zeros(3)
    # camera poses in the anchor frame (scalar loops: numba sends every small `@` to BLAS)
    R_AC = np.empty((m, 3, 3))
    p_AC = np.empty((m, 3))
    bA = np.empty(3)
    for i in range(m):
        R = R_OC[i]
        for j in range(3):
            for k in range(3):
                R_AC[i, j, k] = RA[0, j] * R[0, k] + RA[1, j] * R[1, k] + RA[2, j] * R[2, k]
        d0, d1, d2 = p_OC[i, 0] - pA[0], p_OC[i, 1] - pA[1], p_OC[i, 2] - pA[2]
        for j in range(3):
            p_AC[i, j] = RA[0, j] * d0 + RA[1, j] * d1 + RA[2, j] * d2
        for j in range(3):
            bA[j] = R_AC[i, j, 0] * xn[i, 0] + R_AC[i, j, 1] * xn[i, 1] + R_AC[i, j, 2]
        nb = np.sqrt(bA[0] * bA[0] + bA[1] * bA[1] + bA[2] * bA[2])
        for j in range(3):
            bA[j] /= nb
        for j in range(3):      # A += I - bA bA^T, b += (I - bA bA^T) p_AC[i]
            proj = bA[0] * p_AC[i, 0] + bA[1] * p_AC[i, 1] + bA[2] * p_AC[i, 2]
            b[j] += p_AC[i, j] - bA[j] * proj
            for k in range(3):
                A[j, k] += (1.0 if j == k else 0.0) - bA[j] * bA[k]
    s = np.linalg.eigvalsh(A)          # ascending, A symmetric PSD
    if s[0] <= 0.0 or s[2] / s[0] > max_cond:
        return False, pO
    pF = np.linalg.solve(A, b)
    if not (pF[2] >= min_dist and pF[2] <= max_dist) or not np.all(np.isfinite(pF)):
        return False, pO
    # refinement in (alpha, beta, rho) = (x/z, y/z, 1/z) of the anchor frame, Levenberg-Marquardt
    Rt = np.empty((m, 3, 3))
    Rtp = np.empty((m, 3))
    for i in range(m):
        for j in range(3):
            for k in range(3):
                Rt[i, j, k] = R_AC[i, k, j]
        for j in range(3):
            Rtp[i, j] = Rt[i, j, 0] * p_AC[i, 0] + Rt[i, j, 1] * p_AC[i, 1] + Rt[i, j, 2] * p_AC[i, 2]
    x0, x1, x2 = pF[0] / pF[2], pF[1] / pF[2], 1.0 / pF[2]
    lam = 1e-3
    cost = _cost(Rt, Rtp, xn, x0, x1, x2)
    for _ in range(iterations):
        H00 = H01 = H02 = H11 = H12 = H22 = 0.0
        g0 = g1 = g2 = 0.0
        for i in range(m):
            R = Rt[i]
            h0 = R[0, 0] * x0 + R[0, 1] * x1 + R[0, 2] - x2 * Rtp[i, 0]
            h1 = R[1, 0] * x0 + R[1, 1] * x1 + R[1, 2] - x2 * Rtp[i, 1]
            h2 = R[2, 0] * x0 + R[2, 1] * x1 + R[2, 2] - x2 * Rtp[i, 2]
            if h2 <= 0:
                continue
            iz = 1.0 / h2
            u = h0 * iz
            v = h1 * iz
            # d(u, v)/d(h) = [[iz, 0, -u iz], [0, iz, -v iz]]; d h / d x = [R[:,0], R[:,1], -Rtp]
            a0 = iz * (R[0, 0] - u * R[2, 0])
            a1 = iz * (R[0, 1] - u * R[2, 1])
            a2 = iz * (-Rtp[i, 0] + u * Rtp[i, 2])
            b0 = iz * (R[1, 0] - v * R[2, 0])
            b1 = iz * (R[1, 1] - v * R[2, 1])
            b2 = iz * (-Rtp[i, 1] + v * Rtp[i, 2])
            e0 = u - xn[i, 0]
            e1 = v - xn[i, 1]
            H00 += a0 * a0 + b0 * b0
            H01 += a0 * a1 + b0 * b1
            H02 += a0 * a2 + b0 * b2
            H11 += a1 * a1 + b1 * b1
            H12 += a1 * a2 + b1 * b2
            H22 += a2 * a2 + b2 * b2
            g0 += a0 * e0 + b0 * e1
            g1 += a1 * e0 + b1 * e1
            g2 += a2 * e0 + b2 * e1
        improved = False
        step = 0.0
        for _t in range(6):
            ok_s, s0, s1, s2 = _solve_spd3(H00 * (1.0 + lam) + 1e-12, H01, H02, H11 * (1.0 + lam) + 1e-12,
                                           H12, H22 * (1.0 + lam) + 1e-12, g0, g1, g2)
            if not ok_s:      # not positive definite (degenerate rays): the general solver decides
                Hl = np.array([[H00 * (1.0 + lam) + 1e-12, H01, H02], [H01, H11 * (1.0 + lam) + 1e-12, H12],
                               [H02, H12, H22 * (1.0 + lam) + 1e-12]])
                sol = np.linalg.solve(Hl, np.array([g0, g1, g2]))
                s0, s1, s2 = sol[0], sol[1], sol[2]
            dx0, dx1, dx2 = -s0, -s1, -s2
            c_new = _cost(Rt, Rtp, xn, x0 + dx0, x1 + dx1, x2 + dx2)
            if c_new < cost:
                x0 += dx0
                x1 += dx1
                x2 += dx2
                lam = max(lam / 10.0, 1e-10)
                improved = True
                cost = c_new
                step = np.sqrt(dx0 * dx0 + dx1 * dx1 + dx2 * dx2)
                break
            lam *= 10.0
        if not improved or step < 1e-6:
            break
    x = np.array([x0, x1, x2])
    if x[2] <= 0:
        return False, pO
    pF = np.array([x[0] / x[2], x[1] / x[2], 1.0 / x[2]])
    # the baseline is the part of each camera's offset from the anchor perpendicular to the ray to the point
    # (OpenVINS single_gaussnewton: the tangent plane of p_FinA); motion along the ray adds no parallax
    dist = np.sqrt(pF[0] * pF[0] + pF[1] * pF[1] + pF[2] * pF[2])
    u = pF / dist if dist > 0 else pF
    base = 0.0
    for i in range(1, m):
        along = p_AC[i, 0] * u[0] + p_AC[i, 1] * u[1] + p_AC[i, 2] * u[2]
        q0, q1, q2 = p_AC[i, 0] - along * u[0], p_AC[i, 1] - along * u[1], p_AC[i, 2] - along * u[2]
        d = np.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
        if d > base:
            base = d
    if (
        pF[2] < min_dist
        or pF[2] > max_dist
        or not np.all(np.isfinite(pF))
        or base <= 0
        or dist / base > max_baseline_ratio
    ):
        return False, pO
    out = np.empty(3)
    for j in range(3):
        out[j] = RA[j, 0] * pF[0] + RA[j, 1] * pF[1] + RA[j, 2] * pF[2] + pA[j]
    return True, out
