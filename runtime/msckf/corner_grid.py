"""Greedy choice of new corners on the detection grid (numba; the tracker's detection step).

Corners are visited strongest first. A corner is taken unless its min_px_dist occupancy cell is taken
(by an existing track or an earlier choice); the first pass also honours the per-grid-cell quota, the
second fills what is still missing anywhere. A taken corner blocks its 3x3 occupancy neighbourhood.
"""
from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def _block_cell(occupied: np.ndarray, ox: int, oy: int) -> None:
    """Mark occupancy cell (oy, ox) and its 8 neighbours (those inside the grid) as taken."""
    occ_h, occ_w = occupied.shape
    for y in range(max(oy - 1, 0), min(oy + 2, occ_h)):
        for x in range(max(ox - 1, 0), min(ox + 2, occ_w)):
            occupied[y, x] = True


@numba.njit(cache=True, nogil=True)
def block_neighbourhoods(occupied: np.ndarray, uv: np.ndarray, cell: float) -> None:
    """Mark the 3x3 occupancy neighbourhood of each pixel of ``uv`` (K, 2) as taken (in place); occupancy
    cells are ``cell`` px square; pixels beyond the grid count in its border cells."""
    occ_h, occ_w = occupied.shape
    for k in range(uv.shape[0]):
        ox = min(max(int(uv[k, 0] / cell), 0), occ_w - 1)
        oy = min(max(int(uv[k, 1] / cell), 0), occ_h - 1)
        _block_cell(occupied, ox, oy)


@numba.njit(cache=True, nogil=True)
def choose_corners(uv: np.ndarray, occupied: np.ndarray, count: np.ndarray, quota: int, n_wanted: int,
                   cell: float, width: int, height: int) -> np.ndarray:
    """Rows of ``uv`` (K, 2) pixels, strongest first, chosen in order (at most n_wanted); ``occupied``
    (occupancy rows, cols; cells of ``cell`` px) bool and ``count`` (grid_y, grid_x) int64, the tracks per
    detection-grid cell of a ``width`` x ``height`` px image, are updated in place; ``quota``: tracks per
    grid cell the first pass allows."""
    grid_y, grid_x = count.shape
    chosen = np.empty(min(n_wanted, uv.shape[0]), dtype=np.int64)
    n = 0
    for use_quota in (True, False):
        for k in range(uv.shape[0]):
            if n >= n_wanted:
                break
            u, v = uv[k, 0], uv[k, 1]
            ox, oy = int(u / cell), int(v / cell)
            if occupied[oy, ox]:
                continue
            cgx = min(int(u * grid_x / width), grid_x - 1)
            cgy = min(int(v * grid_y / height), grid_y - 1)
            if use_quota and count[cgy, cgx] >= quota:
                continue
            count[cgy, cgx] += 1
            _block_cell(occupied, ox, oy)  # also keeps the second pass off corners already chosen
            chosen[n] = k
            n += 1
    return chosen[:n]
