"""Orientations of a body from its gyro alone (the turning-in-place initializer's rotations)."""
from __future__ import annotations

import numpy as np

from runtime.geometry.so3 import so3_exp


def gyro_orientations(t_ns: np.ndarray, gyro: np.ndarray, bg: np.ndarray,
                      t_query_ns: np.ndarray) -> np.ndarray:
    """R_{I(t0) I(t)} (k, 3, 3) at t_query_ns (inside [t_ns[0], t_ns[-1]]) from the bias-corrected gyro.

    Midpoint rates between samples; a query between two samples takes the partial step."""
    w = 0.5 * (gyro[1:] + gyro[:-1]) - bg
    dt = np.diff(t_ns) * 1e-9
    steps = so3_exp(w * dt[:, None])                     # all increments at once
    R = np.empty((t_ns.shape[0], 3, 3))
    R[0] = np.eye(3)
    for k in range(dt.shape[0]):
        R[k + 1] = R[k] @ steps[k]
    t_query_ns = np.asarray(t_query_ns, dtype=np.int64)
    k = np.clip(np.searchsorted(t_ns, t_query_ns, side="right") - 1, 0, dt.shape[0] - 1)
    partial = so3_exp(w[k] * ((t_query_ns - t_ns[k]) * 1e-9)[:, None])
    return R[k] @ partial
