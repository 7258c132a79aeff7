"""Per-tile view-frustum culling of the ray caster's boxes.

The image is cut into square tiles of `TILE_PX` pixels. For each tile the rays (camera frame, z = 1)
span a small frustum {x/z in [x0, x1], y/z in [y0, y1], z > 0}; a box whose eight corners all lie
beyond one of its planes cannot be hit by any ray of the tile, so the caster skips it there. The test
is conservative (the bounds are widened by `MARGIN`), and the caster still tests the boxes it keeps in
their original order, so culling changes no pixel: it only saves slab tests (on the simulator's rooms
most rays reach 1-3 boxes of a tile instead of the 10-30 of a shelf group).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from runtime.errors import ConfigError

TILE_PX = 16
"""Tile side, pixels."""
MARGIN = 1e-6
"""Widening of each tile's x/z, y/z bounds (camera-frame ray units), so rounding never culls a hit."""


def tile_bounds(rays: np.ndarray, tile_px: int = TILE_PX) -> np.ndarray:
    """(T, 4) [x0, x1, y0, y1] bounds of each tile's rays (H, W, 3 with z = 1), row-major tiles."""
    if not np.allclose(rays[..., 2], 1.0, rtol=0.0, atol=1e-12):
        raise ConfigError("tile culling needs camera-frame rays with z = 1 (divide each ray by its z)")
    H, W = rays.shape[:2]
    ty, tx = -(-H // tile_px), -(-W // tile_px)
    pad = np.full((ty * tile_px, tx * tile_px, 2), np.nan)
    pad[:H, :W] = rays[..., :2]
    blocks = pad.reshape(ty, tile_px, tx, tile_px, 2).transpose(0, 2, 1, 3, 4).reshape(ty * tx, -1, 2)
    lo, hi = np.nanmin(blocks, axis=1), np.nanmax(blocks, axis=1)
    return np.ascontiguousarray(np.stack([lo[:, 0] - MARGIN, hi[:, 0] + MARGIN,
                                          lo[:, 1] - MARGIN, hi[:, 1] + MARGIN], axis=1))


@njit(cache=True, nogil=True, parallel=True)
def tile_flags(
    box_min: np.ndarray,
    box_max: np.ndarray,
    group_start: np.ndarray,
    R_WC: np.ndarray,
    p_WC: np.ndarray,
    bounds: np.ndarray,
    node_left: np.ndarray,
    node_right: np.ndarray,
    node_first: np.ndarray,
    node_count: np.ndarray,
    node_order: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(box, group, node) uint8 flags per tile, (T, B), (T, G), (T, M): 1 where a ray of the tile may
    hit the box (box 0, the room shell, is always 1), a box of the group, a group below the BVH node.

    Groups: group g holds boxes group_start[g] .. group_start[g+1]-1 (box 0 is in none);
    node_*: the flattened BVH over the groups (drivers.sim.bvh.GroupBvh). R_WC must be a rotation
    (the culling inverts it by its transpose; orthogonal to ~MARGIN suffices)."""
    B = box_min.shape[0]
    G = group_start.shape[0] - 1
    M = node_left.shape[0]
    T = bounds.shape[0]
    corners = np.empty((B, 8, 3))
    for b in range(B):
        for c in range(8):
            dx = (box_max[b, 0] if c & 1 else box_min[b, 0]) - p_WC[0]
            dy = (box_max[b, 1] if c & 2 else box_min[b, 1]) - p_WC[1]
            dz = (box_max[b, 2] if c & 4 else box_min[b, 2]) - p_WC[2]
            for k in range(3):   # x_C = R_WC^T (x_W - p_WC)
                corners[b, c, k] = R_WC[0, k] * dx + R_WC[1, k] * dy + R_WC[2, k] * dz
    box_on = np.zeros((T, B), np.uint8)
    group_on = np.zeros((T, G), np.uint8)
    node_on = np.zeros((T, M), np.uint8)
    for t in prange(T):
        x0, x1, y0, y1 = bounds[t, 0], bounds[t, 1], bounds[t, 2], bounds[t, 3]
        box_on[t, 0] = 1
        for b in range(1, B):
            behind = right = left = below = above = True
            for c in range(8):
                x, y, z = corners[b, c, 0], corners[b, c, 1], corners[b, c, 2]
                behind = behind and z <= 0.0     # a NaN corner culls nothing
                right = right and x > x1 * z
                left = left and x < x0 * z
                below = below and y > y1 * z
                above = above and y < y0 * z
            if not (behind or right or left or below or above):
                box_on[t, b] = 1
        for g in range(G):
            for b in range(group_start[g], group_start[g + 1]):
                group_on[t, g] |= box_on[t, b]
        for node in range(M - 1, -1, -1):   # children come after their parent
            if node_left[node] < 0:
                for k in range(node_first[node], node_first[node] + node_count[node]):
                    node_on[t, node] |= group_on[t, node_order[k]]
            else:
                node_on[t, node] = node_on[t, node_left[node]] | node_on[t, node_right[node]]
    return box_on, group_on, node_on
