"""Interpolation of PoseTrajectory at arbitrary stamps."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from runtime.errors import TrajectoryError
from runtime.geometry import PoseTrajectory, interpolate_poses


def make_traj(with_extras: bool = True) -> PoseTrajectory:
    t_ns = np.array([1_000_000_000_000_000_000, 1_000_000_000_100_000_000, 1_000_000_000_250_000_000],
                    dtype=np.int64)
    rot = Rotation.from_rotvec([[0.0, 0.0, 0.0], [0.3, -0.2, 1.0], [0.1, 2.5, -0.3]])
    p = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0], [1.0, 0.0, -1.0]])
    extra = np.arange(9.0).reshape(3, 3) if with_extras else None
    return PoseTrajectory(t_ns, p, rot.as_matrix(), v=extra, bg=extra, ba=extra)


def test_interpolation_matches_scipy_slerp_and_linear_positions():
    traj = make_traj()
    t = traj.t_ns[0] + np.array([0, 25_000_000, 100_000_000, 175_000_000, 250_000_000], dtype=np.int64)
    out = interpolate_poses(traj, t)
    ts = (traj.t_ns - traj.t_ns[0]) * 1e-9
    tq = (t - traj.t_ns[0]) * 1e-9
    slerp = Slerp(ts, Rotation.from_matrix(traj.R))
    np.testing.assert_allclose(out.R, slerp(tq).as_matrix(), atol=1e-12)
    expected_p = np.stack([np.interp(tq, ts, traj.p[:, k]) for k in range(3)], axis=1)
    np.testing.assert_allclose(out.p, expected_p, atol=1e-12)
    np.testing.assert_allclose(out.v, np.stack([np.interp(tq, ts, traj.v[:, k]) for k in range(3)], 1))
    assert out.t_ns.dtype == np.int64 and np.array_equal(out.t_ns, t)


def test_interpolation_outside_range_raises():
    traj = make_traj(False)
    with pytest.raises(TrajectoryError, match="outside"):
        interpolate_poses(traj, [traj.t_ns[-1] + 1])
    with pytest.raises(TrajectoryError):
        interpolate_poses(traj, [traj.t_ns[0] - 1])
    out = interpolate_poses(traj, traj.t_ns)
    assert out.v is None
    np.testing.assert_allclose(out.R, traj.R, atol=1e-12)


def test_unordered_or_empty_trajectory_raises():
    traj = make_traj(False)
    bad = PoseTrajectory(traj.t_ns[::-1], traj.p, traj.R)
    with pytest.raises(TrajectoryError, match="increasing"):
        interpolate_poses(bad, traj.t_ns[:1])
    with pytest.raises(TrajectoryError, match="empty"):
        interpolate_poses(PoseTrajectory(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3, 3))), [0])
