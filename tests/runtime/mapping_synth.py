"""Synthetic mapping windows for the mapping tests: cameras looking at a box-shaped room, with exact
depth maps rendered by ray casting planes (independent of the simulator)."""
from __future__ import annotations

import numpy as np

from models.emulated_da3.analytic import look_at  # noqa: F401  (re-exported for the mapping tests)

K_TEST = np.array([[200.0, 0.0, 79.5], [0.0, 200.0, 59.5], [0.0, 0.0, 1.0]])
W_TEST, H_TEST = 160, 120


def window_poses(n: int = 5, step: float = 0.15) -> np.ndarray:
    """(n,4,4) T_WC of cameras moving sideways along x, looking at +y (the far wall)."""
    return np.stack([look_at(np.array([k * step, 0.0, 1.0]), np.array([k * step + 0.1, 4.0, 1.2]))
                     for k in range(n)])


def render_room_depth(T_WC: np.ndarray, K: np.ndarray = K_TEST, w: int = W_TEST, h: int = H_TEST,
                      room: tuple = (-3, 4, -2, 4, 0, 3)) -> np.ndarray:
    """(h,w) z-depth of the inside of an axis-aligned box room [x0,x1]x[y0,y1]x[z0,z1]."""
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    rays_C = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    R, c = T_WC[:3, :3], T_WC[:3, 3]
    rays_W = rays_C @ R.T
    best = np.full((h, w), np.inf)
    bounds = np.asarray(room, float).reshape(3, 2)
    for axis in range(3):
        for plane in bounds[axis]:
            with np.errstate(divide="ignore", invalid="ignore"):
                s = (plane - c[axis]) / rays_W[..., axis]   # along rays with z_C = 1: s = depth
            s = np.where(s > 1e-6, s, np.inf)
            best = np.minimum(best, s)
    return best
