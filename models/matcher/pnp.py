"""PnP-RANSAC verification of a match set with the paper's gates (loop / revisit acceptance)."""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field

import cv2
import numpy as np

from runtime.errors import ConfigError, DataError


@dataclass(frozen=True)
class PnPGates:
    """Acceptance gates of a PnP verification (paper defaults).

    Attributes:
        min_matches: correspondences needed before trying (50).
        min_inliers: RANSAC inliers needed (30).
        min_inlier_fraction: inliers / correspondences needed (0.25).
        reprojection_px: RANSAC inlier threshold in pixels (2.0).
        iterations: RANSAC iterations; confidence: RANSAC confidence.
    """

    min_matches: int = 50
    min_inliers: int = 30
    min_inlier_fraction: float = 0.25
    reprojection_px: float = 2.0
    iterations: int = 500
    confidence: float = 0.999

    def __post_init__(self) -> None:
        def integer(v: object, least: int) -> bool:
            return isinstance(v, numbers.Integral) and not isinstance(v, bool) and v >= least

        checks = [("min_matches", integer(self.min_matches, 4), "an integer >= 4"),
                  ("min_inliers", integer(self.min_inliers, 4), "an integer >= 4"),
                  ("iterations", integer(self.iterations, 1), "an integer >= 1"),
                  ("min_inlier_fraction", 0.0 <= self.min_inlier_fraction <= 1.0, "in [0, 1]"),
                  ("confidence", 0.0 < self.confidence < 1.0, "in (0, 1)"),
                  ("reprojection_px", 0.0 < self.reprojection_px < math.inf, "a finite number > 0")]
        for name, ok, must in checks:   # NaN fails every comparison
            if not ok:
                raise ConfigError(f"revisits.pnp.{name} must be {must}, got {getattr(self, name)!r}")


@dataclass
class PnPResult:
    """Outcome of `verify_pnp`.

    Attributes:
        accepted: all gates passed.
        reason: 'accepted' or why it was rejected.
        T_CW: (4,4) pose of the camera that saw `uv` w.r.t. the points' frame (None if PnP failed).
        inliers: (K,) indices of the inlier correspondences.
        n_matches, n_inliers, inlier_fraction: the gated quantities.
        rmse_px: reprojection RMSE of the inliers.
    """

    accepted: bool
    reason: str
    T_CW: np.ndarray | None = None
    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    n_matches: int = 0
    n_inliers: int = 0
    inlier_fraction: float = 0.0
    rmse_px: float = float("nan")


def verify_pnp(
    points_W: np.ndarray,
    uv: np.ndarray,
    K: np.ndarray,
    gates: PnPGates = PnPGates(),
    distortion: np.ndarray | None = None,
) -> PnPResult:
    """Estimate the pose of a camera from 3-D points and their matched pixels, then gate it.

    Args:
        points_W: (N, 3) points in frame W (e.g. back-projected depth of the reference keyframe).
        uv: (N, 2) pixels of the same points in the query image.
        K: (3, 3) query camera intrinsics; distortion: its OpenCV coefficients (None = rectified).
        gates: the acceptance gates.
    """
    P = np.asarray(points_W, np.float64)
    x = np.asarray(uv, np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or x.shape != (P.shape[0], 2):
        raise DataError(f"need (N,3) points and (N,2) pixels, got {P.shape} and {x.shape}")
    ok = np.isfinite(P).all(1) & np.isfinite(x).all(1)
    P, x, ids = P[ok], x[ok], np.flatnonzero(ok)
    n = len(P)
    if n < gates.min_matches:
        return PnPResult(False, f"too few matches ({n} < {gates.min_matches})", n_matches=n)
    dist = np.zeros(5) if distortion is None else np.asarray(distortion, np.float64)
    found, rvec, tvec, inl = cv2.solvePnPRansac(
        P,
        x,
        np.asarray(K, np.float64),
        dist,
        iterationsCount=gates.iterations,
        reprojectionError=gates.reprojection_px,
        confidence=gates.confidence,
        flags=cv2.SOLVEPNP_EPNP,
    )
    if not found or inl is None or len(inl) < 4:
        return PnPResult(False, "PnP-RANSAC found no pose", n_matches=n)
    inl = inl.ravel()
    rvec, tvec = cv2.solvePnPRefineLM(P[inl], x[inl], np.asarray(K, np.float64), dist, rvec, tvec)
    proj, _ = cv2.projectPoints(P, rvec, tvec, np.asarray(K, np.float64), dist)
    err = np.linalg.norm(proj.reshape(-1, 2) - x, axis=1)
    depth = (cv2.Rodrigues(rvec)[0] @ P.T + tvec).T[:, 2]
    inl = np.flatnonzero((err < gates.reprojection_px) & (depth > 0))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = cv2.Rodrigues(rvec)[0], tvec.ravel()
    frac = len(inl) / n
    rmse = float(np.sqrt(np.mean(err[inl] ** 2))) if len(inl) else float("nan")
    res = PnPResult(False, "", T, ids[inl], n, len(inl), frac, rmse)
    if len(inl) < gates.min_inliers:
        res.reason = f"too few inliers ({len(inl)} < {gates.min_inliers})"
    elif frac < gates.min_inlier_fraction:
        res.reason = f"inlier fraction {frac:.2f} < {gates.min_inlier_fraction}"
    else:
        res.accepted, res.reason = True, "accepted"
    return res
