"""Synthetic submap-graph geometry shared by the graph tests: camera poses in a gravity-aligned map frame
and exact point correspondences between two submaps."""
from __future__ import annotations

import math

import numpy as np

from runtime.geometry import make_pose

# camera axes (z forward, x right, y down) in a body frame with x forward, z up
R_BODY_CAM = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def rz(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def loop_poses(n: int, radius: float = 3.0) -> np.ndarray:
    """(n,4,4) T_MS on a horizontal circle, each camera looking outwards: the last sees what the first saw."""
    Ts = []
    for j in range(n):
        a = 2 * math.pi * j / n
        Ts.append(make_pose(rz(a) @ R_BODY_CAM, np.array([radius * math.cos(a), radius * math.sin(a), 1.0])))
    return np.array(Ts)


def corresponding_points(Ta: np.ndarray, la: float, Tb: np.ndarray, lb: float, k: int,
                         rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """k true points 2-6 m in front of camera a, as p_a in S_a and p_b in S_b without lambda."""
    pc = np.column_stack([rng.uniform(-2, 2, k), rng.uniform(-1, 1, k), rng.uniform(2, 6, k)])
    X = pc @ Ta[:3, :3].T + Ta[:3, 3]
    pa = (X - Ta[:3, 3]) @ Ta[:3, :3] / math.exp(la)
    pb = (X - Tb[:3, 3]) @ Tb[:3, :3] / math.exp(lb)
    return pa, pb
