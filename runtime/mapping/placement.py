"""Placement of depth pixels in the map, paper eq. (placement):

    p_M = T_MS_j T_S_jC_i ( e^lambda_j d_ji(u) K^-1 u ),  d_ji = s_hat_j s_ji d^DA3_ji.

The scale acts on depth only: the metric translations of T_S_jC_i are never rescaled (a similarity
applied to the whole window would scale the VIO baselines and displace every non-centre frame).
"""
from __future__ import annotations

import numpy as np


def backproject(depth: np.ndarray, K: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(P,3) camera-frame points d K^-1 [u v 1]^T for pixels (u, v) with depths `depth` (metres)."""
    K = np.asarray(K, np.float64)
    x = (np.asarray(u, np.float64) - K[0, 2]) / K[0, 0]
    y = (np.asarray(v, np.float64) - K[1, 2]) / K[1, 1]
    d = np.asarray(depth, np.float64)
    return np.stack([x * d, y * d, d], axis=-1)


def ray_points(depth: np.ndarray, K: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(P,3) float32 camera-frame points of float32 depths at pixels (u, v): d (u - cx) / fx, d (v - cy) /
    fy, d in float64, rounded to float32. The mapper stores its points so, and the map archive stores the
    depths and pixels alone (tools.map_archive.point_rays, schema 3): both give back the same points, bit
    for bit. Archives on disk depend on this arithmetic: do not change it (not even its order)."""
    K = np.asarray(K, np.float64)
    d = np.asarray(depth, np.float32).astype(np.float64)
    x = (np.asarray(u, np.float64) - K[0, 2]) / K[0, 0]
    y = (np.asarray(v, np.float64) - K[1, 2]) / K[1, 1]
    return np.stack([x * d, y * d, d], axis=-1).astype(np.float32)


def place_points(points_C: np.ndarray, image: np.ndarray, T_SC: np.ndarray, T_MS: np.ndarray,
                 lam: float = 0.0) -> np.ndarray:
    """Map-frame points of camera-frame points (eq. placement).

    Args:
        points_C: (P,3) d K^-1 u of each point in the camera of its image (metres, with s_hat s_ji).
        image: (P,) index of each point's image in T_SC.
        T_SC: (N,4,4) T_S_jC_i, metric VIO poses of the images relative to the submap frame.
        T_MS: (4,4) the submap's pose Q_j = T_MS_j.
        lam: residual log-depth scale lambda_j (scales each point along its own camera ray).

    Returns:
        (P,3) float64 points in M.
    """
    P = np.asarray(points_C, np.float64) * np.exp(float(lam))
    idx = np.asarray(image, np.intp)
    T_SC = np.asarray(T_SC, np.float64)
    T_MC = np.asarray(T_MS, np.float64) @ T_SC  # (N,4,4)
    R = T_MC[idx, :3, :3]
    t = T_MC[idx, :3, 3]
    return np.einsum("pij,pj->pi", R, P) + t
