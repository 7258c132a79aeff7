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
    # camera poses in the anchor frame
    R_AC = np.empty((m, 3, 3))
    p_AC = np.empty((m, 3))
    for i in range(m):
        R_AC[i] = RA.T @ R_OC[i]
        p_AC[i] = RA.T @ (p_OC[i] - pA)
        f = np.array([xn[i, 0], xn[i, 1], 1.0])
        bA = R_AC[i] @ f
        bA = bA / np.sqrt(bA @ bA)
        Bp = np.eye(3) - np.outer(bA, bA)
        A += Bp
        b += Bp @ p_AC[i]
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
        Rt[i] = R_AC[i].T
        Rtp[i] = Rt[i] @ p_AC[i]
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
        Hs = np.array([[H00, H01, H02], [H01, H11, H12], [H02, H12, H22]])
        g = np.array([g0, g1, g2])
        improved = False
        step = 0.0
        for _t in range(6):
            Hl = Hs.copy()
            for k in range(3):
                Hl[k, k] += lam * Hs[k, k] + 1e-12
            dx = -np.linalg.solve(Hl, g)
            c_new = _cost(Rt, Rtp, xn, x0 + dx[0], x1 + dx[1], x2 + dx[2])
            if c_new < cost:
                x0 += dx[0]
                x1 += dx[1]
                x2 += dx[2]
                lam = max(lam / 10.0, 1e-10)
                improved = True
                cost = c_new
                step = np.sqrt(dx @ dx)
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
    dist = np.sqrt(pF @ pF)
    u = pF / dist if dist > 0 else pF
    base = 0.0
    for i in range(1, m):
        q = p_AC[i] - (p_AC[i] @ u) * u
        d = np.sqrt(q @ q)
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
    return True, RA @ pF + pA
