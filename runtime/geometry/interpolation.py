"""Interpolation of pose trajectories at arbitrary int64-nanosecond stamps.

Positions (and velocity / biases when present) are interpolated linearly, rotations along the
SO(3) geodesic between the two bracketing poses.
"""
from __future__ import annotations

import numpy as np

from runtime.errors import TrajectoryError
from runtime.geometry.so3 import so3_interpolate
from runtime.geometry.trajectory import PoseTrajectory


def bracket(t_ref_ns: np.ndarray, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices i and fractions alpha with t = t_ref[i] + alpha (t_ref[i+1] - t_ref[i]), alpha in [0, 1].

    t_ref_ns must be strictly increasing with at least two stamps (or one stamp queried exactly);
    stamps outside [t_ref[0], t_ref[-1]] raise TrajectoryError.
    """
    t_ref_ns = np.asarray(t_ref_ns, dtype=np.int64).reshape(-1)
    t_ns = np.asarray(t_ns, dtype=np.int64).reshape(-1)
    if t_ref_ns.size == 0:
        raise TrajectoryError("cannot interpolate an empty trajectory")
    if t_ref_ns.size > 1 and np.any(np.diff(t_ref_ns) <= 0):
        raise TrajectoryError("trajectory stamps are not strictly increasing")
    if t_ns.size and (t_ns.min() < t_ref_ns[0] or t_ns.max() > t_ref_ns[-1]):
        bad = t_ns[(t_ns < t_ref_ns[0]) | (t_ns > t_ref_ns[-1])][0]
        raise TrajectoryError(f"stamp {int(bad)} ns is outside the trajectory range "
                              f"[{int(t_ref_ns[0])}, {int(t_ref_ns[-1])}] ns")
    if t_ref_ns.size == 1:
        return np.zeros(t_ns.size, dtype=np.int64), np.zeros(t_ns.size)
    i = np.clip(np.searchsorted(t_ref_ns, t_ns, side="right") - 1, 0, t_ref_ns.size - 2)
    span = t_ref_ns[i + 1] - t_ref_ns[i]
    alpha = (t_ns - t_ref_ns[i]).astype(np.float64) / span.astype(np.float64)
    return i, alpha


def interpolate_poses(traj: PoseTrajectory, t_ns: np.ndarray) -> PoseTrajectory:
    """The trajectory `traj` (poses T_WB) evaluated at the stamps t_ns (int64 ns, inside its range).

    Raises TrajectoryError for stamps outside [traj.t_ns[0], traj.t_ns[-1]] or an unordered trajectory.
    The result has the same optional fields (v, bg, ba) as `traj`, linearly interpolated, and a
    copy of its meta.
    """
    t_ns = np.asarray(t_ns, dtype=np.int64).reshape(-1)
    i, alpha = bracket(traj.t_ns, t_ns)
    j = np.minimum(i + 1, len(traj) - 1)

    def lerp(a: np.ndarray | None) -> np.ndarray | None:
        if a is None:
            return None
        return a[i] + alpha[:, None] * (a[j] - a[i])

    R = so3_interpolate(traj.R[i], traj.R[j], alpha)
    return PoseTrajectory(t_ns, lerp(traj.p), R, lerp(traj.v), lerp(traj.bg), lerp(traj.ba), dict(traj.meta))
