"""The relative rotation of two views from matched image points: no depth, no scale, no network.

Two models are fitted to the same correspondences (undistorted normalized coordinates) and the one the
points support is kept:
- the essential matrix (OpenCV's five-point USAC with local optimisation), for views with parallax;
- a pure rotation, f_b = R_BA f_a on unit bearings (a two-point Kabsch RANSAC refined on its inliers, the
  turning-start initializer's), for views whose translation is too small against the scene's depth to be
  seen. There every translation fits the epipolar constraint, and the essential matrix's rotation may be
  the wrong one of its twisted pair; of that pair, the one nearer the pure rotation's is taken in every
  case.
The rotation model is kept when it explains at least `rotation_share` as many points as the essential
matrix: the parallax is then within the threshold, and a rotation is all the points can tell.

Used by the calibration-withheld bring-up when no depth model is given (`runtime.bringup`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from runtime.geometry.so3 import kabsch_rotation

#: the rotation model's threshold against the essential matrix's: its error is a 2-D distance with both
#: views' noise, the epipolar one a 1-D distance
ROTATION_THRESHOLD_FACTOR = 2.0


@dataclass(frozen=True)
class TwoViewRotation:
    """A relative rotation and what supports it.

    Attributes:
        R_BA: (3, 3) rotation taking view A's camera-frame vectors into view B's (X_B = R_BA X_A + t).
        model: "essential" or "rotation" (the model kept).
        inliers: correspondences the kept model explains.
        points: correspondences offered.
        essential_inliers: the essential matrix's RANSAC inliers (0 when it failed).
        rotation_inliers: the pure rotation's inliers.
    """

    R_BA: np.ndarray
    model: str
    inliers: int
    points: int
    essential_inliers: int
    rotation_inliers: int


def bearings(xy: np.ndarray) -> np.ndarray:
    """Unit bearing vectors (n, 3) of normalized camera coordinates xy (n, 2)."""
    b = np.column_stack([xy, np.ones(xy.shape[0])])
    return b / np.linalg.norm(b, axis=1, keepdims=True)


def rotation_ransac(a: np.ndarray, b: np.ndarray, threshold_rad: float, rng: np.random.Generator,
                    iterations: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Rotation R with b ~ R a for bearings a, b (n, 3): 2-point RANSAC, Kabsch refit on the inliers.

    Returns R and the inlier mask (angle between R a_i and b_i below threshold_rad); the identity and the
    best mask when fewer than 3 bearings agree."""
    n = a.shape[0]
    cos_thr = np.cos(threshold_rad)
    pairs = np.array([rng.choice(n, 2, replace=False) for _ in range(iterations)], dtype=np.intp)
    best = np.zeros(n, dtype=bool)
    if pairs.size:
        R_all = kabsch_rotation(a[pairs], b[pairs])              # every hypothesis at once
        inliers = np.einsum("knj,nj->kn", a @ np.swapaxes(R_all, -1, -2), b) > cos_thr
        best = inliers[np.argmax(inliers.sum(axis=1))]          # the first of the most supported
    if best.sum() < 3:
        return np.eye(3), best
    R = kabsch_rotation(a[best], b[best])
    return R, np.einsum("ij,ij->i", a @ R.T, b) > cos_thr


def essential_rotation(xy_a: np.ndarray, xy_b: np.ndarray, threshold: float,
                       R_near: np.ndarray) -> tuple[np.ndarray | None, int]:
    """(R_BA, RANSAC inliers) from the essential matrix of normalized points (OpenCV's five-point USAC with
    local optimisation at `threshold`, normalized units); (None, 0) when it fails. Of the two rotations an
    essential matrix holds (the twisted pair, 180 deg apart about the baseline), the one nearer `R_near`
    (the pure-rotation fit) is returned: the cheirality test that usually tells them apart
    (`cv2.recoverPose`) picks the wrong one in about a tenth of the views with little parallax."""
    import cv2

    a = np.ascontiguousarray(xy_a, np.float64)
    b = np.ascontiguousarray(xy_b, np.float64)
    E, mask = cv2.findEssentialMat(a, b, np.eye(3), cv2.USAC_ACCURATE, 0.999, float(threshold))
    if E is None or E.shape[0] < 3 or mask is None:
        return None, 0
    n_in = int(np.count_nonzero(mask))
    if n_in < 5:
        return None, 0
    R1, R2, _ = cv2.decomposeEssentialMat(E[:3])
    R1, R2 = np.asarray(R1, np.float64), np.asarray(R2, np.float64)
    near = np.asarray(R_near, np.float64)
    # trace(R_near^T R) grows as the angle between them shrinks
    return (R1 if np.trace(near.T @ R1) >= np.trace(near.T @ R2) else R2), n_in


def two_view_rotation(xy_a: np.ndarray, xy_b: np.ndarray, threshold: float, min_inliers: int = 15,
                      rotation_share: float = 0.9) -> TwoViewRotation | None:
    """The rotation between two views from matched normalized points (N, 2) each (module docstring).

    Args:
        threshold: inlier threshold in normalized units (pixels / focal length).
        min_inliers: fewer supporting points than this for both models: None.
        rotation_share: keep the pure rotation when its inliers reach this share of the essential
            matrix's.
    """
    xy_a, xy_b = np.asarray(xy_a, np.float64), np.asarray(xy_b, np.float64)
    if xy_a.shape != xy_b.shape or xy_a.ndim != 2 or xy_a.shape[1] != 2:
        raise ValueError(f"two_view_rotation: point arrays (N, 2) of the same shape, got {xy_a.shape} "
                         f"and {xy_b.shape}")
    ok = np.all(np.isfinite(xy_a), axis=1) & np.all(np.isfinite(xy_b), axis=1)
    xy_a, xy_b = xy_a[ok], xy_b[ok]
    n = len(xy_a)
    if n < max(min_inliers, 5):
        return None
    # a fixed seed: the same points give the same rotation model
    R_rot, inl = rotation_ransac(bearings(xy_a), bearings(xy_b), ROTATION_THRESHOLD_FACTOR * threshold,
                                 np.random.default_rng(0), iterations=128)
    n_rot = int(inl.sum())
    R_ess, n_ess = essential_rotation(xy_a, xy_b, threshold, R_rot)
    if n_rot >= min_inliers and (R_ess is None or n_rot >= rotation_share * n_ess):
        return TwoViewRotation(R_rot, "rotation", n_rot, n, n_ess, n_rot)
    if R_ess is None or n_ess < min_inliers:
        return None
    return TwoViewRotation(R_ess, "essential", n_ess, n, n_ess, n_rot)
