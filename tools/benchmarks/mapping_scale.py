"""How well the submap graph's residual log-depth scales lambda_j match the truth (`davio bench mapping`).

For submap j, lambda*_j = median over its retained points of log(z_true / z), with z a point's depth in
its own camera (before lambda) and z_true the true depth rendered at its pixel: the lambda that would put
the submap's median point on the true surface along its ray. lambda_j - lambda*_j is the graph's scale
error; lambda*_j alone is the error with the graph's scales off (lambda = 0). A constant offset of
lambda_j against lambda*_j moves every far point along its ray and costs the map its F-score while the
trajectory can still improve (the MH_03 whole-run case in BENCHMARKS.md).
"""
from __future__ import annotations

from typing import Any

import numpy as np


def true_log_scale(submap: Any, truth: Any, width: int, height: int) -> float:
    """lambda*_j of one submap (NaN when no point sees a rendered surface)."""
    ratios = []
    for i, t in enumerate(submap.frame_t_ns):
        P = np.asarray(submap.points_C[submap.image == i], np.float64)
        if len(P) == 0:
            continue
        view = truth.render_view(int(t), submap.K, width, height)
        z = P[:, 2]
        front = z > 0
        uv = (P[front] / z[front, None]) @ np.asarray(submap.K, np.float64).T
        u = np.round(uv[:, 0]).astype(np.int64)
        v = np.round(uv[:, 1]).astype(np.int64)
        h, w = view.depth.shape
        inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        zt = view.depth[v[inside], u[inside]]
        ok = np.isfinite(zt) & (zt > 0)
        ratios.append(np.log(zt[ok] / z[front][inside][ok]))
    r = np.concatenate(ratios) if ratios else np.zeros(0)
    return float(np.median(r)) if len(r) else float("nan")


def lambda_errors(submaps: list, truth: Any, width: int, height: int) -> dict:
    """Summary of lambda_j against lambda*_j over the submaps: means, RMS of lambda - lambda* (the graph),
    RMS of lambda* (lambda = 0) and their correlation."""
    lam = np.array([float(s.lam) for s in submaps])
    ref = np.array([true_log_scale(s, truth, width, height) for s in submaps])
    ok = np.isfinite(ref)
    lam, ref = lam[ok], ref[ok]
    if len(lam) == 0:
        return {"submaps": 0}
    corr = float(np.corrcoef(lam, ref)[0, 1]) if len(lam) > 2 and lam.std() > 0 and ref.std() > 0 else None
    return {"submaps": int(len(lam)), "lambda_mean": float(lam.mean()), "true_mean": float(ref.mean()),
            "rms_error": float(np.sqrt(np.mean((lam - ref) ** 2))), "rms_error_lambda_zero":
            float(np.sqrt(np.mean(ref ** 2))), "correlation": corr}
