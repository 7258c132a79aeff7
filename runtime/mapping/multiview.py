"""Multi-view rejection of a window's depths (paper Sec. V.D) and the confidence filter.

A depth sample of image i is re-observed when another image j of the same window confirms it: the
point, moved into C_j with the metric VIO poses, projects inside image j in front of the camera and
its z agrees with image j's depth there within `rel_depth` (10 %). Flying pixels at depth
discontinuities and inconsistent depths fail this test; true surfaces seen twice pass.

A sample that no other image sees at all (outside their images, behind them, or on pixels without a
valid depth) is neither confirmed nor contradicted: `multiview_test` reports it as unseen, and the
mapper keeps it or not by `MappingConfig.multiview_keep_unseen`. The paper's rule ("retained only if
another frame re-observes it") drops it.
"""
from __future__ import annotations

import numpy as np


def sample_grid(height: int, width: int, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) int pixel coordinates of a regular grid with `stride` pixels, centred in its cells."""
    off = stride // 2
    v, u = np.mgrid[off:height:stride, off:width:stride]
    return u.ravel(), v.ravel()


def multiview_test(points_S: np.ndarray, source: np.ndarray, T_SC: np.ndarray, depths: np.ndarray,
                   K: np.ndarray, rel_depth: float = 0.10) -> tuple[np.ndarray, np.ndarray]:
    """Each point (in the submap frame S, from image `source[p]`) against the OTHER images of the window.

    Args:
        points_S: (P,3) points in S (metres).
        source: (P,) image index of each point.
        T_SC: (N,4,4) poses of the images in S.
        depths: (N,H,W) corrected depth maps of the images (non-finite or <= 0: invalid).
        K: (3,3) pinhole intrinsics of the depth maps.
        rel_depth: agreement tolerance, relative to the other image's depth.

    Returns:
        (agree, seen), (P,) bool each: `agree` when at least one other image's depth at the point's
        pixel matches its z within `rel_depth`; `seen` when at least one other image holds a valid
        depth where the point projects (inside the image, in front of the camera). A point seen but
        never agreed with is contradicted; one never seen is unverifiable within the window.
        (`seen` is True wherever `agree` is: agreeing needs a valid depth there.)
    """
    n, h, w = depths.shape
    agree = np.zeros(len(points_S), bool)
    seen = np.zeros(len(points_S), bool)
    pts = np.asarray(points_S, np.float64)
    for j in range(n):
        T_CS = np.linalg.inv(T_SC[j])
        cand = np.flatnonzero((source != j) & ~agree)
        if cand.size == 0:
            continue
        p = pts[cand] @ T_CS[:3, :3].T + T_CS[:3, 3]
        z = p[:, 2]
        zs = np.where(z > 1e-6, z, 1.0)
        u = np.round(K[0, 0] * p[:, 0] / zs + K[0, 2]).astype(np.int64)
        v = np.round(K[1, 1] * p[:, 1] / zs + K[1, 2]).astype(np.int64)
        ok = (z > 1e-6) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        idx = cand[ok]
        d = depths[j][v[ok], u[ok]]
        good = np.isfinite(d) & (d > 0)
        seen[idx[good]] = True
        match = np.zeros(ok.sum(), bool)
        match[good] = np.abs(z[ok][good] - d[good]) <= rel_depth * d[good]
        agree[idx[match]] = True
    return agree, seen


def confidence_mask(conf: np.ndarray, percentile: float) -> np.ndarray:
    """Bool mask of confidences at or above the window's `percentile` (finite values only)."""
    c = np.asarray(conf, np.float64)
    finite = np.isfinite(c)
    if not finite.any() or percentile <= 0:
        return finite
    return finite & (c >= np.percentile(c[finite], percentile))
