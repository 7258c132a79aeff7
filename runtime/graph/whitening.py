"""Noise models of the graph factors (paper Sec. V.C): the odometry drift model and the ray-aligned
point covariance. All sigmas in metres (translation, points) or radians (rotation)."""
from __future__ import annotations

import math

import numpy as np

from runtime.graph.config import GraphConfig


def drift_sigmas(distance_m: float, cfg: GraphConfig) -> tuple[float, float]:
    """(sigma_t [m], sigma_r [rad]) of the odometry drift over a VIO distance |t_ab| (m)."""
    d = abs(float(distance_m))
    sigma_t = max(cfg.drift_trans_sigma_min_m, cfg.drift_trans_sigma_per_m * d)
    sigma_r = math.radians(max(cfg.drift_rot_sigma_min_deg, cfg.drift_rot_sigma_per_m_deg * d))
    return sigma_t, sigma_r


def odometry_weights(Z_ab: np.ndarray, cfg: GraphConfig) -> np.ndarray:
    """(6,) diagonal W_o for r_o = [rho (m), phi (rad)] from the drift model at |t_ab| of Z_ab."""
    sigma_t, sigma_r = drift_sigmas(float(np.linalg.norm(Z_ab[:3, 3])), cfg)
    return np.array([1.0 / sigma_t] * 3 + [1.0 / sigma_r] * 3)


def ray_covariance(p: np.ndarray, cfg: GraphConfig) -> np.ndarray:
    """(K,3,3) covariances (m^2) of points p (K,3) given in their submap frame S (metres).

    The ray is the direction of p from the origin of S and the depth is the range |p|; sigma along
    the ray = max(point_sigma_along_frac |p|, floor), across = max(point_sigma_across_frac |p|, floor).
    A point at the origin gets the isotropic floor.
    """
    p = np.asarray(p, np.float64)
    rng = np.linalg.norm(p, axis=1)
    u = p / np.where(rng > 0, rng, 1.0)[:, None]
    s_par = np.maximum(cfg.point_sigma_along_frac * rng, cfg.point_sigma_min_m)
    s_perp = np.maximum(cfg.point_sigma_across_frac * rng, cfg.point_sigma_min_m)
    uu = u[:, :, None] * u[:, None, :]
    return (s_par**2 - s_perp**2)[:, None, None] * uu + (s_perp**2)[:, None, None] * np.eye(3)


def point_whitening(R_a: np.ndarray, P_a: np.ndarray, R_b: np.ndarray, P_b: np.ndarray,
                    cfg: GraphConfig) -> np.ndarray:
    """(K,3,3) W with W Sigma W^T = I for the point residual r = R_a P_a + t_a - R_b P_b - t_b.

    R_a, R_b: (K,3,3) rotations R_MS of the two submaps; P_a, P_b: (K,3) scaled points e^lambda p in
    S_a, S_b (metres). Sigma = R_a C(P_a) R_a^T + R_b C(P_b) R_b^T, the covariance of the difference of
    two independently measured points, each with its ray-aligned covariance C (`ray_covariance`).
    W = L^-1 with Sigma = L L^T, so |W r|^2 = r^T Sigma^-1 r.
    """
    Ca = ray_covariance(P_a, cfg)
    Cb = ray_covariance(P_b, cfg)
    S = R_a @ Ca @ np.swapaxes(R_a, 1, 2) + R_b @ Cb @ np.swapaxes(R_b, 1, 2)
    return np.linalg.inv(np.linalg.cholesky(S))
