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

