"""Confidence-gated point sampling from a DA3 prediction (paper Sec. IV-A).

Per image: pixels with finite positive depth whose confidence exceeds the image's 25th percentile,
spread over a 4x4 grid, at most 100 per image (highest confidence first within each cell).
"""
from __future__ import annotations

import numpy as np

from models.depth_model import DepthPrediction
from runtime.ffinit.config import FFInitConfig
from runtime.ffinit.window import ImageObservations


def sample_pixels(depth: np.ndarray, conf: np.ndarray, cfg: FFInitConfig,
                  rng: np.random.Generator) -> np.ndarray:
    """(M, 2) pixel coordinates (u, v) sampled from one image's depth and confidence maps."""
    h, w = depth.shape
    valid = np.isfinite(depth) & (depth > 0) & np.isfinite(conf)
    if not np.any(valid):
        return np.zeros((0, 2))
    thr = np.percentile(conf[valid], cfg.conf_percentile)
    good = valid & (conf > thr)
    cells = cfg.grid_rows * cfg.grid_cols
    per_cell = max(1, cfg.max_points_per_image // cells)
    picked = []
    for r in range(cfg.grid_rows):
        for c in range(cfg.grid_cols):
            v0, v1 = r * h // cfg.grid_rows, (r + 1) * h // cfg.grid_rows
            u0, u1 = c * w // cfg.grid_cols, (c + 1) * w // cfg.grid_cols
            vv, uu = np.nonzero(good[v0:v1, u0:u1])
            if vv.size == 0:
                continue
            take = rng.choice(vv.size, size=min(per_cell, vv.size), replace=False)
            picked.append(np.column_stack([uu[take] + u0, vv[take] + v0]))
    if not picked:
        return np.zeros((0, 2))
    return np.concatenate(picked).astype(np.float64)[: cfg.max_points_per_image]


def observations_from_prediction(pred: DepthPrediction, cfg: FFInitConfig, K: np.ndarray | None = None,
                                 seed: int = 0) -> list[ImageObservations]:
    """ImageObservations for every image of an unconditioned DA3 prediction.

    K: rectified intrinsics to compute normalized coordinates with (the rig's, when calibrated);
    default: DA3's predicted intrinsics of each image.
    """
    rng = np.random.default_rng(seed)
    out = []
    for i in range(pred.depth.shape[0]):
        uv = sample_pixels(pred.depth[i], pred.conf[i], cfg, rng)
        Ki = pred.K[i] if K is None else K
        z = (uv - Ki[:2, 2]) / np.array([Ki[0, 0], Ki[1, 1]])
        iu, iv = uv[:, 0].astype(int), uv[:, 1].astype(int)
        T_CiC0 = pred.T_CW[i]
        R_C0Ci = T_CiC0[:3, :3].T
        p_C0Ci = -R_C0Ci @ T_CiC0[:3, 3]
        out.append(ImageObservations(z=z, depth=pred.depth[i][iv, iu].astype(np.float64),
                                     conf=pred.conf[i][iv, iu].astype(np.float64),
                                     R_C0Ci=R_C0Ci, p_C0Ci=p_C0Ci))
    return out
