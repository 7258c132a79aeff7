"""Reference points visible from a camera path (paper Sec. VI: "Surface metrics score reference
points visible from the reference camera path").

A point counts as visible when at least one view sees it: it lies in front of that camera,
projects inside its image, and agrees with the view's true z-depth at that pixel within
max(abs_tol_m, rel_tol * depth). The depth test removes points hidden behind nearer surfaces
(occlusion) and points on the back of a surface.
"""
from __future__ import annotations

import numpy as np

from runtime.errors import DataError


def visible_points(points_W: np.ndarray, T_WC: np.ndarray, depths: np.ndarray, K: np.ndarray,
                   abs_tol_m: float = 0.03, rel_tol: float = 0.02) -> np.ndarray:
    """(M,) bool: which points some view sees.

    Args:
        points_W: (M,3) points in the world frame, metres.
        T_WC: (N,4,4) camera poses of the views (x_W = T_WC x_C; OpenCV axes, z forward).
        depths: (N,H,W) true z-depth of each view through the pinhole K (non-finite or <= 0: no
            surface at that pixel).
        K: (3,3) pinhole intrinsics of the depth maps; pixel (0, 0) is the centre of the
            top-left pixel.
        abs_tol_m, rel_tol: a point agrees with the depth d at its pixel when
            |z - d| <= max(abs_tol_m, rel_tol * d).

    Raises:
        DataError: shapes that do not fit together.
    """
    pts = np.asarray(points_W, np.float64)
    T = np.asarray(T_WC, np.float64)
    D = np.asarray(depths)
    K = np.asarray(K, np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise DataError(f"points must be (M,3), got {pts.shape}")
    if T.ndim != 3 or T.shape[1:] != (4, 4) or D.ndim != 3 or D.shape[0] != T.shape[0]:
        raise DataError(f"need T_WC (N,4,4) and depths (N,H,W) for the same N, got {T.shape} and {D.shape}")
    if K.shape != (3, 3):
        raise DataError(f"K must be (3,3), got {K.shape}")
    h, w = D.shape[1:]
    seen = np.zeros(len(pts), bool)
    for T_i, d_i in zip(T, D, strict=True):
        cand = np.flatnonzero(~seen)
        if cand.size == 0:
            break
        R, c = T_i[:3, :3], T_i[:3, 3]
        p = (pts[cand] - c) @ R          # R^T (x - c): the camera frame
        z = p[:, 2]
        front = z > 1e-6
        cand, p, z = cand[front], p[front], z[front]
        u = np.round(K[0, 0] * p[:, 0] / z + K[0, 1] * p[:, 1] / z + K[0, 2]).astype(np.int64)
        v = np.round(K[1, 1] * p[:, 1] / z + K[1, 2]).astype(np.int64)
        inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        cand, z = cand[inside], z[inside]
        d = np.asarray(d_i[v[inside], u[inside]], np.float64)
        ok = np.isfinite(d) & (d > 0)
        tol = np.maximum(abs_tol_m, rel_tol * np.where(ok, d, 0.0))
        agree = ok & (np.abs(z - np.where(ok, d, 0.0)) <= tol)
        seen[cand[agree]] = True
    return seen
