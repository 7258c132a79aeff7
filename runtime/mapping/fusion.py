"""Voxel fusion (paper Sec. V.D): retained points averaged into cubic voxels (4 cm by default).

Each voxel holds the weighted sums of the positions and grey values of the points that fell in it,
so a submap can be taken out again exactly (`integrate(..., sign=-1)`) when the graph moves it and
re-added at its new pose. The grid is a sorted array of packed voxel keys with parallel accumulators;
added points wait as per-voxel sums until they are as many as the grid's voxels (`VoxelGrid`).
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

    Added points are first reduced per call (one `np.unique` over the call's points) and kept as pending
    per-voxel sums; the pending sums join the sorted grid in one pass when they hold as many rows as the
    grid (or `MERGE_MIN_ROWS`), and before anything reads the grid or takes points out. Joining the grid at
    every call cost a sort of the whole grid per submap, which made fusing an archive quadratic in its
    length (BENCHMARKS.md "Fusing a long run's archive at the end"); now the grid is copied once per
    merge, and a merge comes after as many pending rows as the grid holds. (The live mapper reads the grid's
    size after every window, so its small grid merges at every window: one pass, not the former sort.)

    Args:
        voxel_m: voxel edge length, metres (> 0).
        pending_rows: the most pending rows kept before they join the grid; None: as many as the grid
            holds, at least MERGE_MIN_ROWS; 0: every call joins the grid at once.
    """

    MERGE_MIN_ROWS = 1 << 20
    """Pending voxel rows below which they wait for more (a few tens of submaps)."""

    def __init__(self, voxel_m: float = 0.04, pending_rows: int | None = None) -> None:
        if not voxel_m > 0:
            raise ValueError(f"voxel size must be > 0, got {voxel_m}")
        if pending_rows is not None and pending_rows < 0:
            raise ValueError(f"pending_rows must be >= 0 or None, got {pending_rows}")
        self.voxel_m = float(voxel_m)
        self.pending_rows = pending_rows
        self._keys = np.zeros(0, np.int64)
        self._w = np.zeros(0, np.float64)          # sum of weights
        self._wp = np.zeros((0, 3), np.float64)    # sum of weight * position
        self._wg = np.zeros(0, np.float64)         # sum of weight * grey
        self._n = np.zeros(0, np.int64)            # number of points
        self._pending: list[tuple[np.ndarray, ...]] = []
        self._pending_rows = 0

    @property
    def keys(self) -> np.ndarray:
        """(V,) int64 sorted packed keys of the voxels (`voxel_keys`)."""
        self._merge()
        return self._keys

    def __len__(self) -> int:
        self._merge()
        return int(self._keys.size)

    def reduce(self, points: np.ndarray, grey: np.ndarray | None = None, weights: np.ndarray | None = None,
               sign: int = 1) -> tuple[np.ndarray, ...] | None:
        """Per-voxel sums of points (P,3) with grey values (P,) and weights (P,), times `sign`: (sorted unique
        keys, weights, weighted positions (V,3), weighted greys, counts); None for no point."""
        pts = np.asarray(points, np.float64).reshape(-1, 3)
        if pts.shape[0] == 0:
            return None
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
        return uk, add_w, add_p, add_g, add_n

    def integrate(self, points: np.ndarray, grey: np.ndarray | None = None,
                  weights: np.ndarray | None = None, sign: int = 1) -> None:
        """Add (sign=+1) or remove (sign=-1) points (P,3) with grey values (P,) and weights (P,)."""
        sums = self.reduce(points, grey, weights, sign)
        if sums is None:
            return
        uk, add_w, add_p, add_g, add_n = sums
        m = len(uk)
        if sign > 0:
            self._pending.append((uk, add_w, add_p, add_g, add_n))
            self._pending_rows += m
            limit = self.pending_rows
            if limit is None:
                limit = max(self._keys.size, self.MERGE_MIN_ROWS)
            if self._pending_rows >= limit:
                self._merge()
            return
        self._merge()
        pos, hit = self._locate(uk)
        if not hit.all():
            raise ValueError(f"{int((~hit).sum())} voxels removed that were never integrated")
        self._add_at(pos, hit, add_w, add_p, add_g, add_n)
        keep = self._n > 0
        if not keep.all():
            self._keys, self._w, self._wp, self._wg, self._n = (
                self._keys[keep], self._w[keep], self._wp[keep], self._wg[keep], self._n[keep])

    def _locate(self, uk: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(insertion places in the sorted grid, whether the grid already holds the voxel) of sorted keys."""
        pos = np.searchsorted(self._keys, uk)
        hit = pos < self._keys.size
        hit[hit] = self._keys[pos[hit]] == uk[hit]
        return pos, hit

    def _add_at(self, pos: np.ndarray, hit: np.ndarray, w: np.ndarray, wp: np.ndarray, wg: np.ndarray,
                n: np.ndarray) -> None:
        """Add the sums of the rows marked `hit` to the grid's voxels at `pos` (unique places)."""
        hp = pos[hit]
        self._w[hp] += w[hit]
        self._wp[hp] += wp[hit]
        self._wg[hp] += wg[hit]
        self._n[hp] += n[hit]

    def _merge(self) -> None:
        """Join the pending sums to the grid: the pending rows reduced among themselves (one sort of
        them), then added where the grid has their voxel and inserted in key order where it has not (one
        pass over the grid; it is never sorted again)."""
        if not self._pending:
            return
        parts, self._pending, self._pending_rows = self._pending, [], 0
        if len(parts) == 1:
            uk, w, wp, wg, n = parts[0]
        else:
            uk, inv = np.unique(np.concatenate([q[0] for q in parts]), return_inverse=True)
            m = len(uk)
            w = np.bincount(inv, np.concatenate([q[1] for q in parts]), m)
            wp_all = np.concatenate([q[2] for q in parts])
            wp = np.stack([np.bincount(inv, wp_all[:, a], m) for a in range(3)], axis=1)
            del wp_all
            wg = np.bincount(inv, np.concatenate([q[3] for q in parts]), m)
            n_all = np.concatenate([q[4] for q in parts]).astype(np.float64)    # exact below 2^53
            n = np.bincount(inv, n_all, m).astype(np.int64)
            del parts, inv, n_all
        pos, hit = self._locate(uk)
        self._add_at(pos, hit, w, wp, wg, n)
        new = ~hit
        if new.any():                    # sorted keys inserted at non-decreasing places stay sorted
            at = pos[new]
            self._keys = np.insert(self._keys, at, uk[new])
            self._w = np.insert(self._w, at, w[new])
            self._wp = np.insert(self._wp, at, wp[new], axis=0)
            self._wg = np.insert(self._wg, at, wg[new])
            self._n = np.insert(self._n, at, n[new])

    def points(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(positions (V,3) weighted means, grey (V,) uint8, point count (V,)) of every voxel."""
        self._merge()
        w = np.maximum(self._w, 1e-12)
        grey = np.clip(np.round(self._wg / w), 0, 255).astype(np.uint8)
        return self._wp / w[:, None], grey, self._n.copy()

    def nbytes(self) -> int:
        """Bytes of the grid's arrays and the pending sums."""
        arrays = [self._keys, self._w, self._wp, self._wg, self._n, *(a for q in self._pending for a in q)]
        return int(sum(a.nbytes for a in arrays))
