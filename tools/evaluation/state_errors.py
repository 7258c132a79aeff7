"""Errors of an estimated start-up state against ground truth: true velocity at a time (the trajectory's
own or a central difference) and the yaw-free velocity / gravity-direction errors."""
from __future__ import annotations

from typing import Any

import numpy as np


def state_errors(R_OI: np.ndarray, v_OI: np.ndarray, R_WI: np.ndarray,
                 v_WI: np.ndarray) -> tuple[float, float]:
    """(velocity error in the IMU frame m/s, gravity-direction error deg): both independent of yaw."""
    ez = np.array([0.0, 0.0, 1.0])
    vel = float(np.linalg.norm(R_OI.T @ v_OI - R_WI.T @ v_WI))
    c = float(np.clip((R_OI.T @ ez) @ (R_WI.T @ ez), -1.0, 1.0))
    return vel, float(np.degrees(np.arccos(c)))


def gt_velocity(gt: Any, t_ns: int, h_s: float = 0.02) -> np.ndarray:
    """True velocity (world frame, m/s) at t_ns: the trajectory's own, else a central difference
    of its positions over +-h_s (ground truths without velocity, e.g. EuRoC MH_03's TUM file)."""
    from runtime.geometry import interpolate_poses

    if gt.v is not None:
        return interpolate_poses(gt, np.array([t_ns], np.int64)).v[0]
    h = int(h_s * 1e9)
    t = np.clip(np.array([t_ns - h, t_ns + h], np.int64), gt.t_ns[0], gt.t_ns[-1])
    p = interpolate_poses(gt, t).p
    return (p[1] - p[0]) / ((t[1] - t[0]) * 1e-9)
