"""The camera's rotation between two frames from their tracks' bearings alone (a turn in place)."""
from __future__ import annotations

import numpy as np

from runtime.geometry.so3 import kabsch_rotation


def bearings(xy: np.ndarray) -> np.ndarray:
    """Unit bearing vectors (n, 3) of normalized camera coordinates xy (n, 2)."""
    b = np.column_stack([xy, np.ones(xy.shape[0])])
    return b / np.linalg.norm(b, axis=1, keepdims=True)


def rotation_ransac(a: np.ndarray, b: np.ndarray, threshold_rad: float, rng: np.random.Generator,
                    iterations: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Rotation R with b ~ R a for bearings a, b (n, 3): 2-point RANSAC, Kabsch refit on the inliers.

    Returns R and the inlier mask (angle between R a_i and b_i below threshold_rad)."""
    n = a.shape[0]
    best = np.zeros(n, dtype=bool)
    cos_thr = np.cos(threshold_rad)
    for _ in range(iterations):
        i, j = rng.choice(n, 2, replace=False)
        R = kabsch_rotation(a[[i, j]], b[[i, j]])
        inl = np.einsum("ij,ij->i", a @ R.T, b) > cos_thr
        if inl.sum() > best.sum():
            best = inl
    if best.sum() < 3:
        return np.eye(3), best
    R = kabsch_rotation(a[best], b[best])
    return R, np.einsum("ij,ij->i", a @ R.T, b) > cos_thr
