"""numba kernel turning radiance into a noisy 8-bit image (gain, vignetting, shot + read noise)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange


@njit(parallel=True, cache=True, nogil=True, fastmath=True)
def expose(
    radiance: np.ndarray,
    gain: float,
    vignette: np.ndarray,
    read_noise: float,
    shot_noise: float,
    normals: np.ndarray,
    offset: int,
    out: np.ndarray,
) -> None:
    """out = clip(rint(s + sqrt(read^2 + shot * s) * n), 0, 255) with s = radiance * gain * vignette.

    `normals` is a bank of standard normal samples read cyclically from `offset` (one per pixel).
    """
    H, W = radiance.shape
    n = normals.shape[0]
    r2 = read_noise * read_noise
    for v in prange(H):
        for u in range(W):
            s = radiance[v, u] * gain * vignette[v, u]
            var = r2 + shot_noise * max(s, 0.0)
            if var > 0.0:
                s += math.sqrt(var) * normals[(offset + v * W + u) % n]
            x = math.floor(s + 0.5)
            out[v, u] = 0 if x < 0.0 else (255 if x > 255.0 else np.uint8(x))
