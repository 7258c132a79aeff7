"""Feature triangulation (numba): linear solve in the anchor camera with a conditioning check, then
Levenberg-Marquardt refinement in anchored inverse depth, with depth and baseline checks (OpenVINS
FeatureInitializer logic, our own implementation).
"""

from __future__ import annotations

import numpy as np
from numba import njit


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
    s = np.linalg.svd(A)[1]
    if s[2] <= 0.0 or s[0] / s[2] > max_cond:
        return False, pO
    pF = np.linalg.solve(A, b)
    if not (pF[2] >= min_dist and pF[2] <= max_dist) or not np.all(np.isfinite(pF)):
        return False, pO
    # refinement in (alpha, beta, rho) = (x/z, y/z, 1/z) of the anchor frame
    x = np.array([pF[0] / pF[2], pF[1] / pF[2], 1.0 / pF[2]])
    lam = 1e-3

    def cost_of(xv: np.ndarray) -> float:
        c = 0.0
        for i in range(m):
            # point in camera i: R_AC^T ([a, b, 1] - rho p_AC) / rho  (scale-free)
            h = R_AC[i].T @ (np.array([xv[0], xv[1], 1.0]) - xv[2] * p_AC[i])
            if h[2] <= 0:
                return 1e30
            e0 = h[0] / h[2] - xn[i, 0]
            e1 = h[1] / h[2] - xn[i, 1]
            c += e0 * e0 + e1 * e1
        return c

    cost = cost_of(x)
    for _ in range(iterations):
        Hs = np.zeros((3, 3))
        g = np.zeros(3)
        for i in range(m):
            Rt = R_AC[i].T
            h = Rt @ (np.array([x[0], x[1], 1.0]) - x[2] * p_AC[i])
            if h[2] <= 0:
                continue
            dh = np.empty((3, 3))
            dh[:, 0] = Rt[:, 0]
            dh[:, 1] = Rt[:, 1]
            dh[:, 2] = -(Rt @ p_AC[i])
            Jp = np.array(
                [[1.0 / h[2], 0.0, -h[0] / (h[2] * h[2])], [0.0, 1.0 / h[2], -h[1] / (h[2] * h[2])]]
            )
            J = Jp @ dh
            e = np.array([h[0] / h[2] - xn[i, 0], h[1] / h[2] - xn[i, 1]])
            Hs += J.T @ J
            g += J.T @ e
        improved = False
        for _t in range(6):
            Hl = Hs + lam * np.diag(np.diag(Hs)) + 1e-12 * np.eye(3)
            dx = -np.linalg.solve(Hl, g)
            xn_ = x + dx
            c_new = cost_of(xn_)
            if c_new < cost:
                x = xn_
                lam = max(lam / 10.0, 1e-10)
                improved = c_new < cost - 1e-16
                cost = c_new
                break
            lam *= 10.0
        if not improved or np.sqrt(dx @ dx) < 1e-6:
            break
    if x[2] <= 0:
        return False, pO
    pF = np.array([x[0] / x[2], x[1] / x[2], 1.0 / x[2]])
    base = 0.0
    for i in range(1, m):
        d = np.sqrt(p_AC[i] @ p_AC[i])
        if d > base:
            base = d
    dist = np.sqrt(pF @ pF)
    if (
        pF[2] < min_dist
        or pF[2] > max_dist
        or not np.all(np.isfinite(pF))
        or base <= 0
        or dist / base > max_baseline_ratio
    ):
        return False, pO
    return True, RA @ pF + pA
