"""Start-up state errors against ground truth: closed-form velocities and yaw-free error definitions."""
from __future__ import annotations

import numpy as np
import pytest

from runtime.geometry import PoseTrajectory, so3_exp
from tools.evaluation.state_errors import gt_velocity, state_errors


def test_gt_velocity_central_difference_matches_the_analytic_velocity():
    t = np.arange(0, 2_000_000_000, 5_000_000, dtype=np.int64)
    s = t * 1e-9
    p = np.column_stack([np.sin(s), 0.5 * s**2, np.zeros_like(s)])
    v = np.column_stack([np.cos(s), s, np.zeros_like(s)])
    R = np.tile(np.eye(3), (len(t), 1, 1))
    with_v = PoseTrajectory(t, p, R, v)
    without_v = PoseTrajectory(t, p, R)
    k = 1_000_000_000
    assert np.allclose(gt_velocity(with_v, k), [np.cos(1.0), 1.0, 0.0], atol=1e-4)
    assert np.allclose(gt_velocity(without_v, k), [np.cos(1.0), 1.0, 0.0], atol=1e-3)


def test_state_errors_ignore_yaw_and_see_tilt():
    R_WI = so3_exp(np.array([0.1, -0.2, 0.3]))
    v_W = np.array([0.5, -0.2, 0.1])
    yaw = so3_exp(np.array([0.0, 0.0, 1.2]))  # another gauge of the same state
    vel, grav = state_errors(yaw @ R_WI, yaw @ v_W, R_WI, v_W)
    assert vel == pytest.approx(0.0, abs=1e-12) and grav == pytest.approx(0.0, abs=1e-6)
    tilt = so3_exp(np.array([np.deg2rad(2.0), 0.0, 0.0]))
    vel, grav = state_errors(tilt @ R_WI, tilt @ v_W + 0.0, R_WI, v_W)
    assert grav == pytest.approx(2.0, abs=1e-6) and vel == pytest.approx(0.0, abs=1e-12)
    vel, _ = state_errors(R_WI, v_W + R_WI @ np.array([0.0, 0.3, 0.4]), R_WI, v_W)
    assert vel == pytest.approx(0.5)
