"""Voxel fusion (paper Sec. V.D): retained points averaged into cubic voxels (4 cm by default).

Each voxel holds the weighted sums of the positions and grey values of the points that fell in it,
so a submap can be taken out again exactly (`integrate(..., sign=-1)`) when the graph moves it and
re-added at its new pose. The grid is a sorted array of packed voxel keys with parallel accumulators:
merging a submap is one `np.unique` and one sorted merge, O(voxels + points).
"""
from __future__ import annotations

import numpy as np

_BITS = 21
_OFFSET = 1 << (_BITS - 1)
_MASK = (1 << _BITS) - 1


def voxel_keys(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """(P,) int64 packed keys of the voxels containing `points` (P,3), metres.

    Raises:
        ValueError: a point lies beyond +-2^20 voxels of the origin (42 km at 4 cm).
    """
    ijk = np.floor(np.asarray(points, np.float64) / voxel_m).astype(np.int64)
    if ijk.size and (np.abs(ijk).max() >= _OFFSET):
        raise ValueError(f"point beyond the voxel grid's range (+-{_OFFSET * voxel_m:.0f} m)")
    ijk += _OFFSET
    return (ijk[:, 0] << (2 * _BITS)) | (ijk[:, 1] << _BITS) | ijk[:, 2]


def key_centres(keys: np.ndarray, voxel_m: float) -> np.ndarray:
    """(V,3) centres of the voxels with packed `keys`."""
    k = np.asarray(keys, np.int64)
    ijk = np.stack([(k >> (2 * _BITS)) & _MASK, (k >> _BITS) & _MASK, k & _MASK], axis=1) - _OFFSET
    return (ijk + 0.5) * voxel_m


class VoxelGrid:
    """Weighted average of points per voxel.

    Args:
        voxel_m: voxel edge length, metres (> 0).
    """

    def __init__(self, voxel_m: float = 0.04) -> None:
        if not voxel_m > 0:
            raise ValueError(f"voxel size must be > 0, got {voxel_m}")
        self.voxel_m = float(voxel_m)
        self.keys = np.zeros(0, np.int64)
        self.w = np.zeros(0, np.float64)          # sum of weights
        self.wp = np.zeros((0, 3), np.float64)    # sum of weight * position
        self.wg = np.zeros(0, np.float64)         # sum of weight * grey
        self.n = np.zeros(0, np.int64)            # number of points

    def __len__(self) -> int:
        return int(self.keys.size)

    def integrate(self, points: np.ndarray, grey: np.ndarray | None = None,
                  weights: np.ndarray | None = None, sign: int = 1) -> None:
        """Add (sign=+1) or remove (sign=-1) points (P,3) with grey values (P,) and weights (P,)."""
        pts = np.asarray(points, np.float64).reshape(-1, 3)
        if pts.shape[0] == 0:
            return
        if not np.isfinite(pts).all():
            raise ValueError("non-finite points cannot be fused")
        g = np.zeros(len(pts)) if grey is None else np.asarray(grey, np.float64).reshape(-1)
        w = np.ones(len(pts)) if weights is None else np.asarray(weights, np.float64).reshape(-1)
        if g.shape[0] != len(pts) or w.shape[0] != len(pts):
            raise ValueError("points, grey and weights must have one row per point")
        keys = voxel_keys(pts, self.voxel_m)
        uk, inv = np.unique(keys, return_inverse=True)
        m = len(uk)
        add_w = sign * np.bincount(inv, w, m)
        add_p = sign * np.stack([np.bincount(inv, w * pts[:, a], m) for a in range(3)], axis=1)
        add_g = sign * np.bincount(inv, w * g, m)
        add_n = sign * np.bincount(inv, minlength=m).astype(np.int64)
        pos = np.searchsorted(self.keys, uk)
        hit = pos < self.keys.size
        hit[hit] = self.keys[pos[hit]] == uk[hit]
        hp = pos[hit]
        self.w[hp] += add_w[hit]
        self.wp[hp] += add_p[hit]
        self.wg[hp] += add_g[hit]
        self.n[hp] += add_n[hit]
        new = ~hit
        if sign < 0 and new.any():
            raise ValueError(f"{int(new.sum())} voxels removed that were never integrated")
        if new.any():
            keys_all = np.concatenate([self.keys, uk[new]])
            order = np.argsort(keys_all, kind="stable")
            self.keys = keys_all[order]
            self.w = np.concatenate([self.w, add_w[new]])[order]
            self.wp = np.concatenate([self.wp, add_p[new]])[order]
            self.wg = np.concatenate([self.wg, add_g[new]])[order]
            self.n = np.concatenate([self.n, add_n[new]])[order]
        if sign < 0:
            keep = self.n > 0
            if not keep.all():
                self.keys, self.w, self.wp, self.wg, self.n = (
                    self.keys[keep], self.w[keep], self.wp[keep], self.wg[keep], self.n[keep])

    def points(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(positions (V,3) weighted means, grey (V,) uint8, point count (V,)) of every voxel."""
        w = np.maximum(self.w, 1e-12)
        grey = np.clip(np.round(self.wg / w), 0, 255).astype(np.uint8)
        return self.wp / w[:, None], grey, self.n.copy()

    def nbytes(self) -> int:
        return int(self.keys.nbytes + self.w.nbytes + self.wp.nbytes + self.wg.nbytes + self.n.nbytes)
