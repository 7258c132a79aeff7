"""A submap's points stored as depths along pixel rays (schema 3): a third of the bytes of x, y, z.

The mapper's points are float32 depths at pixels of its rectified camera K, brought to x, y, z by
`runtime.mapping.placement.ray_points`. The archive keeps each point's depth and pixel and reads the
points back through the same function, so what it reads is what was written, bit for bit. Points that
are not so (another writer's, or pixels beyond 16 bits) are stored as x, y, z.
"""
from __future__ import annotations

import numpy as np

from runtime.mapping.placement import ray_points

PIXEL_MAX = np.iinfo(np.uint16).max


def encode_rays(points_C: np.ndarray, K: np.ndarray) -> dict[str, np.ndarray] | None:
    """{"depth": (P,) float32 metres, "pixel_u", "pixel_v": (P,) uint16} of camera-frame points
    `points_C` (P,3) float32 under pinhole `K`, or None when reading them back (`decode_rays`) would not
    give `points_C` exactly. (u and v apart: a grid's columns compress to a sixth of the (P,2) pairs.)"""
    P = np.asarray(points_C)
    if P.dtype != np.float32 or P.ndim != 2 or P.shape[1] != 3:
        return None
    K = np.asarray(K, np.float64)
    z = P[:, 2]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        u = np.rint(P[:, 0] / z * K[0, 0] + K[0, 2])
        v = np.rint(P[:, 1] / z * K[1, 1] + K[1, 2])
    if not (np.isfinite(u).all() and np.isfinite(v).all()):
        return None
    if len(P) and (min(u.min(), v.min()) < 0 or max(u.max(), v.max()) > PIXEL_MAX):
        return None
    pixel_u, pixel_v = u.astype(np.uint16), v.astype(np.uint16)
    if not np.array_equal(decode_rays(z, pixel_u, pixel_v, K), P):
        return None
    return {"depth": np.ascontiguousarray(z), "pixel_u": pixel_u, "pixel_v": pixel_v}


def decode_rays(depth: np.ndarray, pixel_u: np.ndarray, pixel_v: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(P,3) float32 camera-frame points of depths (P,) at pixels (pixel_u, pixel_v) (P,) under pinhole
    `K`."""
    return ray_points(depth, K, np.asarray(pixel_u, np.float64), np.asarray(pixel_v, np.float64))
