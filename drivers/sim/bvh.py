"""A bounding-volume hierarchy over the scene's box groups (flattened for the numba ray caster)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LEAF_SIZE = 2
"""Most groups per leaf node."""


@dataclass
class GroupBvh:
    """Flattened binary tree; node 0 is the root.

    Attributes:
        node_min, node_max: (M,3) node bounds, m.
        left, right: (M,) child node indices (-1 for leaves).
        axis: (M,) split axis of inner nodes (children ordered low to high along it).
        first, count: (M,) leaf range in `order`.
        order: (G,) group indices in leaf order.
    """

    node_min: np.ndarray
    node_max: np.ndarray
    left: np.ndarray
    right: np.ndarray
    axis: np.ndarray
    first: np.ndarray
    count: np.ndarray
    order: np.ndarray


def build_bvh(group_min: np.ndarray, group_max: np.ndarray) -> GroupBvh:
    """Median-split BVH over (G,3) group bounds (G may be 0: one empty leaf)."""
    nodes: list[list] = []
    order: list[int] = []
    centre = 0.5 * (group_min + group_max)

    def build(idx: np.ndarray) -> int:
        me = len(nodes)
        lo = group_min[idx].min(axis=0) if idx.size else np.zeros(3)
        hi = group_max[idx].max(axis=0) if idx.size else np.zeros(3)
        nodes.append([lo, hi, -1, -1, 0, len(order), 0])
        if idx.size <= LEAF_SIZE:
            order.extend(int(i) for i in idx)
            nodes[me][6] = int(idx.size)
            return me
        ax = int(np.argmax(centre[idx].max(axis=0) - centre[idx].min(axis=0)))
        srt = idx[np.argsort(centre[idx, ax], kind="stable")]
        half = srt.size // 2
        left = build(srt[:half])
        right = build(srt[half:])
        nodes[me][2], nodes[me][3], nodes[me][4] = left, right, ax
        return me

    build(np.arange(group_min.shape[0]))
    return GroupBvh(
        node_min=np.array([n[0] for n in nodes], np.float64).reshape(-1, 3),
        node_max=np.array([n[1] for n in nodes], np.float64).reshape(-1, 3),
        left=np.array([n[2] for n in nodes], np.int64),
        right=np.array([n[3] for n in nodes], np.int64),
        axis=np.array([n[4] for n in nodes], np.int64),
        first=np.array([n[5] for n in nodes], np.int64),
        count=np.array([n[6] for n in nodes], np.int64),
        order=np.array(order, np.int64),
    )


def frustum_active(
    bvh: GroupBvh,
    group_min: np.ndarray,
    group_max: np.ndarray,
    R_WC: np.ndarray,
    p_WC: np.ndarray,
    xy_min: np.ndarray,
    xy_max: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """(node_active, group_active) uint8 flags: 0 where a group's box lies wholly outside the view
    frustum {x/z in [xy_min[0], xy_max[0]], y/z in [xy_min[1], xy_max[1]], z > 0} of a camera at
    (R_WC, p_WC); a node is active when any group below it is. Conservative: never culls a box
    that a ray of the frustum can hit."""
    g = group_min.shape[0]
    node_active = np.zeros(bvh.left.shape[0], np.uint8)
    if g == 0:
        return node_active, np.zeros(0, np.uint8)
    corners = np.empty((g, 8, 3))
    for c in range(8):
        corners[:, c, 0] = np.where(c & 1, group_max[:, 0], group_min[:, 0])
        corners[:, c, 1] = np.where(c & 2, group_max[:, 1], group_min[:, 1])
        corners[:, c, 2] = np.where(c & 4, group_max[:, 2], group_min[:, 2])
    p = (corners - p_WC) @ R_WC  # camera-frame corners (x_C = R_WC^T (x_W - p_WC))
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    outside = (
        np.all(z <= 0.0, axis=1)
        | np.all(x > xy_max[0] * z, axis=1)
        | np.all(x < xy_min[0] * z, axis=1)
        | np.all(y > xy_max[1] * z, axis=1)
        | np.all(y < xy_min[1] * z, axis=1)
    )
    group_active = (~outside).astype(np.uint8)
    for node in range(bvh.left.shape[0] - 1, -1, -1):  # children come after their parent
        if bvh.left[node] < 0:
            groups = bvh.order[bvh.first[node] : bvh.first[node] + bvh.count[node]]
            node_active[node] = 1 if group_active[groups].any() else 0
        else:
            node_active[node] = node_active[bvh.left[node]] | node_active[bvh.right[node]]
    return node_active, group_active
