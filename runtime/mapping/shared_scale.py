"""Relative log-depth scale of consecutive submaps (paper Sec. V.B, eq. shared).

For each image i shared by submaps a and b, m_i = median over aligned valid pixels of
log(d_bi / d_ai); consistent corrected depths e^lambda_a d_ai = e^lambda_b d_bi imply
lambda_b - lambda_a = -m_i, so

    kappa_ab = -mean_i m_i,   sigma_ab = max(0.03, (max_i m_i - min_i m_i) / 2).

When the queue dropped a window and no image is shared, kappa_ab comes from a projected-overlap
depth ratio instead: b's retained points seen from one of a's cameras (through the metric VIO poses)
against a's depth there.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class ScaleLink:
    """A relative-scale constraint lambda_b - lambda_a = kappa (sigma) between submaps a and b."""

    a: int
    b: int
    kappa: float
    sigma: float
    method: str        # "shared" | "overlap"
    n_images: int
    n_pixels: int
    m: list

    def as_dict(self) -> dict:
        return {"a": self.a, "b": self.b, "kappa": self.kappa, "sigma": self.sigma, "method": self.method,
                "n_images": self.n_images, "n_pixels": self.n_pixels, "m": list(self.m)}


def median_log_ratio(d_b: np.ndarray, d_a: np.ndarray, min_pixels: int = 200) -> tuple[float, int] | None:
    """(median log(d_b / d_a) over pixels valid in both, pixel count), or None below min_pixels."""
    d_a = np.asarray(d_a, np.float64)
    d_b = np.asarray(d_b, np.float64)
    ok = np.isfinite(d_a) & np.isfinite(d_b) & (d_a > 0) & (d_b > 0)
    n = int(ok.sum())
    if n < min_pixels:
        return None
    return float(np.median(np.log(d_b[ok] / d_a[ok]))), n


def kappa_sigma(m: list[float], min_sigma: float = 0.03) -> tuple[float, float]:
    """kappa_ab and sigma_ab of eq. (shared) from the per-image median log ratios m_i."""
    arr = np.asarray(m, np.float64)
    return float(-arr.mean()), float(max(min_sigma, 0.5 * (arr.max() - arr.min())))


def shared_link(a: int, b: int, depths_a: dict[int, np.ndarray], depths_b: dict[int, np.ndarray],
                min_pixels: int = 200, min_sigma: float = 0.03) -> ScaleLink | None:
    """The shared-image link of submaps a, b from their corrected depth maps keyed by frame stamp."""
    m, npx = [], 0
    for t in sorted(set(depths_a) & set(depths_b)):
        r = median_log_ratio(depths_b[t], depths_a[t], min_pixels)
        if r is not None:
            m.append(r[0])
            npx += r[1]
    if not m:
        return None
    kappa, sigma = kappa_sigma(m, min_sigma)
    return ScaleLink(a, b, kappa, sigma, "shared", len(m), npx, m)


def overlap_link(a: int, b: int, points_b_O: np.ndarray, T_OC_a: np.ndarray, depth_a: np.ndarray,
                 K: np.ndarray, min_pixels: int = 200, min_sigma: float = 0.03) -> ScaleLink | None:
    """The projected-overlap link: b's points (P,3, odometry frame, lambda_b = 0) projected into a
    camera of submap a (pose T_OC_a) and compared with a's corrected depth map there."""
    T_CO = np.linalg.inv(np.asarray(T_OC_a, np.float64))
    p = np.asarray(points_b_O, np.float64) @ T_CO[:3, :3].T + T_CO[:3, 3]
    z = p[:, 2]
    front = z > 1e-3
    p, z = p[front], z[front]
    h, w = depth_a.shape
    u = np.round(K[0, 0] * p[:, 0] / z + K[0, 2]).astype(np.int64)
    v = np.round(K[1, 1] * p[:, 1] / z + K[1, 2]).astype(np.int64)
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    if inside.sum() < min_pixels:
        return None
    d_a = depth_a[v[inside], u[inside]]
    zb = z[inside]
    # only points that see the same surface (within 30 %) vote; occluded or disoccluded ones do not
    ok = np.isfinite(d_a) & (d_a > 0) & (np.abs(np.log(zb / np.where(d_a > 0, d_a, 1.0))) < 0.3)
    r = median_log_ratio(zb[ok], d_a[ok], min_pixels)
    if r is None:
        return None
    kappa, sigma = kappa_sigma([r[0]], min_sigma)
    return ScaleLink(a, b, kappa, max(sigma, 2 * min_sigma), "overlap", 0, r[1], [r[0]])
