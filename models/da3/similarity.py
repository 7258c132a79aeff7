"""Umeyama similarity fit between two point sets (used to recover DA3's metric scale)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Similarity:
    """y ≈ s R x + t, fitted by least squares.

    Attributes:
        s: scale; R: (3,3) rotation; t: (3,) translation.
        rmse_y: RMSE of the residuals in y's units.
        spread_x: RMS distance of the x points to their centroid (x's units).
    """

    s: float
    R: np.ndarray
    t: np.ndarray
    rmse_y: float
    spread_x: float


def umeyama_sim3(x: np.ndarray, y: np.ndarray) -> Similarity:
    """Least-squares similarity (Umeyama 1991) mapping points x (N,3) onto y (N,3).

    Raises:
        ValueError: shapes differ, fewer than 2 points, non-finite values, or x has no spread
        (all points coincide), in which case the scale is undefined.
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 2 or x.shape[1] != 3 or x.shape[0] < 2:
        raise ValueError(f"need two (N>=2, 3) point sets of the same shape, got {x.shape} and {y.shape}")
    if not (np.isfinite(x).all() and np.isfinite(y).all()):
        raise ValueError("point sets contain non-finite values")
    mx, my = x.mean(0), y.mean(0)
    xc, yc = x - mx, y - my
    var_x = float((xc**2).sum(1).mean())
    spread = float(np.sqrt(var_x))
    if spread < 1e-9:
        raise ValueError("the source points coincide: the similarity scale is undefined")
    cov = yc.T @ xc / x.shape[0]
    U, d, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    s = float(np.trace(np.diag(d) @ S) / var_x)
    t = my - s * R @ mx
    res = y - (s * (R @ x.T).T + t)
    rmse = float(np.sqrt((res**2).sum(1).mean()))
    return Similarity(s=s, R=R, t=t, rmse_y=rmse, spread_x=spread)
