"""Per-point Newton inversion of the radial-tangential distortion (numba; the tracker's hot path).

Each point iterates on its own until its residual is below ``tol`` (the vectorised numpy form
iterated every point until the worst one converged); a point whose final residual exceeds
``accept`` or whose Jacobian is singular is NaN. Normalized coordinates in, normalized out.
"""
from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def undistort_radtan(xy_d: np.ndarray, k1: float, k2: float, p1: float, p2: float, k3: float,
                     max_iterations: int, tol: float, accept: float) -> np.ndarray:
    """Undistorted normalized coordinates (N, 2) of distorted ones (N, 2)."""
    n = xy_d.shape[0]
    out = np.empty((n, 2))
    for i in range(n):
        xd, yd = xy_d[i, 0], xy_d[i, 1]
        x, y = xd, yd
        ok = True
        for _ in range(max_iterations):
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            ex = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - xd
            ey = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - yd
            if not (abs(ex) > tol or abs(ey) > tol):
                break
            dr = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
            j00 = radial + 2.0 * x * x * dr + 2.0 * p1 * y + 6.0 * p2 * x
            j01 = 2.0 * x * y * dr + 2.0 * p1 * x + 2.0 * p2 * y
            j11 = radial + 2.0 * y * y * dr + 6.0 * p1 * y + 2.0 * p2 * x
            det = j00 * j11 - j01 * j01
            if abs(det) < 1e-12:
                ok = False
                break
            x -= (j11 * ex - j01 * ey) / det
            y -= (-j01 * ex + j00 * ey) / det
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        ex = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - xd
        ey = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - yd
        if ok and abs(ex) <= accept and abs(ey) <= accept:
            out[i, 0], out[i, 1] = x, y
        else:
            out[i, 0], out[i, 1] = np.nan, np.nan
    return out
