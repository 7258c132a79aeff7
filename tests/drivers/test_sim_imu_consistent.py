"""EuRoC-trajectory mode's rendered truth: no position jumps, the gyro's attitude held to the ground truth."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from drivers.euroc import read_euroc_imu_csv
from drivers.sim.imu_consistent import gyro_consistent_attitude, remove_position_jumps
from drivers.sim.recording import SimConfig, SimRecording
from drivers.sim.rig import euroc_default_rig
from drivers.sim.spline import interpolate_rotations
from drivers.trajectory_files import read_trajectory
from runtime.errors import ConfigError, DataError
from runtime.geometry.trajectory import PoseTrajectory
from tests.conftest import shared_path

RATE_HZ = 200.0


def _angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angles of Ra^T Rb, deg."""
    rel = Rotation.from_matrix(np.transpose(Ra, (0, 2, 1)) @ Rb).as_rotvec()
    return np.degrees(np.linalg.norm(rel, axis=1))


def _body_rates(t_ns: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Mean body angular rate over each sample interval, rad/s: Log(R_k^T R_k+1) / dt."""
    rel = Rotation.from_matrix(np.transpose(R[:-1], (0, 2, 1)) @ R[1:]).as_rotvec()
    return rel / (np.diff(t_ns)[:, None] * 1e-9)


def _rate(t: np.ndarray) -> np.ndarray:
    """True body angular rate at times t (s), rad/s, shape t.shape + (3,)."""
    return np.stack([0.4 * np.sin(0.7 * t), 0.3 * np.cos(0.5 * t), 0.2 + 0.1 * np.sin(1.3 * t)], axis=-1)


def _true_motion(seconds: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stamps, true rotations and the true body rates (exact at the stamps) of a smooth tumbling motion."""
    t_ns = np.arange(int(seconds * RATE_HZ) + 1, dtype=np.int64) * int(1e9 / RATE_HZ) + 1_000_000_000
    t = (t_ns - t_ns[0]) * 1e-9
    w = _rate(t)
    sub = 10      # midpoint sub-steps: the truth the gyro samples
    w_sub = _rate(t[:-1, None] + (np.arange(sub) + 0.5)[None, :] / sub / RATE_HZ)
    steps = Rotation.from_rotvec(w_sub.reshape(-1, 3) / sub / RATE_HZ).as_matrix().reshape(-1, sub, 3, 3)
    R = np.empty((t.size, 3, 3))
    R[0] = np.eye(3)
    for k in range(t.size - 1):
        Rk = R[k]
        for j in range(sub):
            Rk = Rk @ steps[k, j]
        R[k + 1] = Rk
    return t_ns, R, w


def _glitched(R_true: np.ndarray, t_ns: np.ndarray, at_s: float, deg: float) -> np.ndarray:
    """R_true with a 0.1 s spell of `deg` about body y (up in 0.05 s, down in 0.05 s), as a fused ground
    truth shows."""
    t = (t_ns - t_ns[0]) * 1e-9
    bump = np.clip(1.0 - np.abs(t - at_s) / 0.05, 0.0, None) * np.radians(deg)
    return R_true @ Rotation.from_rotvec(bump[:, None] * np.array([0.0, 1.0, 0.0])).as_matrix()


def test_the_attitude_follows_the_gyro_through_a_ground_truth_glitch() -> None:
    t_ns, R_true, w = _true_motion(12.0)
    bg = np.array([0.004, -0.002, 0.003])
    rng = np.random.default_rng(0)
    gyro = w + bg + rng.normal(0.0, 1e-4, w.shape)
    R_gt = _glitched(R_true, t_ns, 6.0, 0.5)
    n = t_ns.size
    zeros = np.zeros((n, 3))
    traj = PoseTrajectory(t_ns, zeros, R_gt, zeros, np.tile(bg, (n, 1)), zeros)
    out = gyro_consistent_attitude(traj, t_ns, gyro, smoothing_s=1.0)
    np.testing.assert_array_equal(out.t_ns, t_ns)
    glitch = np.abs((t_ns - t_ns[0]) * 1e-9 - 6.0) < 0.06
    assert _angle_deg(R_gt, R_true)[glitch].max() > 0.45          # the ground truth turns 0.5 deg ...
    assert _angle_deg(out.R, R_true).max() < 0.06                 # ... the output follows the true motion
    # between samples the output turns as the bias-corrected gyro says (the GT's own rate does not)
    w_imu = 0.5 * (gyro[:-1] + gyro[1:]) - bg
    rate_err = np.degrees(np.linalg.norm(_body_rates(t_ns, out.R) - w_imu, axis=1))
    gt_err = np.degrees(np.linalg.norm(_body_rates(t_ns, R_gt) - w_imu, axis=1))
    assert gt_err.max() > 5.0 and rate_err.max() < 0.2
    assert out.bg is not None and np.allclose(out.bg, bg)
    assert out.meta["attitude"].startswith("gyro")


def test_without_ground_truth_biases_a_constant_gyro_bias_is_taken_out() -> None:
    t_ns, R_true, w = _true_motion(20.0)
    rng = np.random.default_rng(1)
    gyro = w + np.array([0.01, -0.008, 0.005]) + rng.normal(0.0, 1e-3, w.shape)   # a bias GT lacks
    traj = PoseTrajectory(t_ns, np.zeros((t_ns.size, 3)), R_true)
    out = gyro_consistent_attitude(traj, t_ns, gyro, smoothing_s=1.0)
    free = np.degrees(0.0137 * 20.0)                   # what the biased gyro alone drifts: 16 deg
    assert _angle_deg(out.R, R_true).max() < 0.05 < 0.01 * free
    assert out.bg is None


def test_a_gyro_that_does_not_belong_to_the_ground_truth_is_refused() -> None:
    t_ns, R_true, w = _true_motion(20.0)
    n = t_ns.size
    zeros = np.zeros((n, 3))
    traj = PoseTrajectory(t_ns, zeros, R_true, zeros, zeros, zeros)   # biases given: zero
    wrong = w + np.array([0.0, 0.05, 0.0])                           # 57 deg of drift over 20 s
    with pytest.raises(DataError, match="drifts"):
        gyro_consistent_attitude(traj, t_ns, wrong)
    with pytest.raises(ConfigError, match="groundtruth_mode"):
        SimConfig(groundtruth_mode="gyro")
    with pytest.raises(ConfigError, match="attitude_smoothing_s"):
        SimConfig(attitude_smoothing_s=float("nan"))


def test_stamps_outside_the_ground_truth_are_left_out_and_bad_input_is_refused() -> None:
    t_ns, R_true, w = _true_motion(2.0)
    traj = PoseTrajectory(t_ns[10:-10], np.zeros((t_ns.size - 20, 3)), R_true[10:-10])
    out = gyro_consistent_attitude(traj, t_ns, w)
    np.testing.assert_array_equal(out.t_ns, t_ns[10:-10])
    with pytest.raises(ConfigError, match="smoothing"):
        gyro_consistent_attitude(traj, t_ns, w, smoothing_s=0.0)
    bad = w.copy()
    bad[50, 1] = np.nan
    with pytest.raises(DataError, match="not finite"):
        gyro_consistent_attitude(traj, t_ns, bad)
    with pytest.raises(DataError, match="fewer than two"):
        gyro_consistent_attitude(traj, t_ns[:5], w[:5])


def test_a_position_jump_is_taken_out_and_the_shape_kept() -> None:
    t_ns, R_true, _ = _true_motion(6.0)
    t = (t_ns - t_ns[0]) * 1e-9
    p_true = np.stack([np.sin(t), 0.5 * t ** 2, np.cos(2.0 * t)], axis=1)     # up to 6 m/s, 4 m/s^2
    step = np.array([-0.063, 0.026, 0.046])                                     # MH_03's, 8.5 cm
    p_gt = p_true + (t >= 3.0)[:, None] * step
    fixed, steps = remove_position_jumps(PoseTrajectory(t_ns, p_gt, R_true))
    assert len(steps) == 1 and np.allclose(steps[0], step, atol=1e-3)
    assert np.abs(fixed.p - p_true).max() < 1e-3          # continuous again, the true shape
    np.testing.assert_array_equal(fixed.R, R_true)
    smooth, none = remove_position_jumps(PoseTrajectory(t_ns, p_true, R_true))
    assert none == [] and np.array_equal(smooth.p, p_true)  # fast smooth motion is no jump
    with pytest.raises(ConfigError):
        remove_position_jumps(PoseTrajectory(t_ns, p_true, R_true), max_step_speed_mps=0.0)


def _replayed(sequence: str, start_s: float, mode: str) -> SimRecording:
    """3 s of a shared EuRoC-trajectory sequence from start_s, rendered in `mode` on a quarter-size camera."""
    rig = euroc_default_rig()
    rig = rig.replace(camera=rig.camera.scaled(0.25, 0.25))
    return SimRecording.from_euroc_imu_gt(
        shared_path("euroc_imu_gt", sequence),
        SimConfig(seconds=3.0, start_s=start_s, seed=0, groundtruth_mode=mode), rig=rig)


def test_mh03_renders_no_jump_the_imu_did_not_measure() -> None:
    """MH_03_medium's ground truth jumps 8.1 cm within one sample at 35.395 s (BENCHMARKS.md,
    "Trajectory"); the default mode renders a continuous motion, "as-recorded" keeps the old behaviour."""
    speed = {}
    for mode in ("imu-consistent", "as-recorded"):
        rec = _replayed("MH_03_medium", 34.0, mode)
        t = rec.imu.t_ns
        p = rec.motion.pose(t)[1]
        speed[mode] = float((np.linalg.norm(np.diff(p, axis=0), axis=1) / (np.diff(t) * 1e-9)).max())
        assert rec.info["groundtruth_mode"] == mode
        if mode == "imu-consistent":
            assert rec.info["position_jumps_removed"] == 1 and 0.08 < rec.info["position_jumps_m"][0] < 0.09
    assert speed["as-recorded"] > 10.0 and speed["imu-consistent"] < 2.0, speed


def test_v102_renders_no_turn_the_gyro_did_not_measure() -> None:
    """V1_02_medium, 3-6 s: the ground truth's angular rate leaves the gyro by several deg/s in short spells;
    the default mode's rendered motion turns as the gyro (less its bias) says."""
    worst = {}
    for mode in ("imu-consistent", "as-recorded"):
        rec = _replayed("V1_02_medium", 3.0, mode)
        t = rec.imu.t_ns
        gap = _body_rates(t, rec.motion.pose(t)[0]) - 0.5 * (rec.imu.gyro[:-1] + rec.imu.gyro[1:])
        worst[mode] = float(np.degrees(np.linalg.norm(gap - np.median(gap, axis=0), axis=1)).max())
    assert worst["as-recorded"] > 3.0 and worst["imu-consistent"] < 0.3, worst


def test_the_real_sequences_jumps() -> None:
    """MH_03 (laser tracker): 25 jumps of 5 mm to 8 cm, the largest at 35.395 s; V1_02 (motion capture):
    none, its fastest flight (2.2 m/s) stays within 0.06 m/s of the local median velocity."""
    gt = read_trajectory(shared_path("euroc_imu_gt", "MH_03_medium") / "groundtruth_tum.txt")
    _, steps = remove_position_jumps(gt)
    sizes = np.linalg.norm(steps, axis=1)
    assert len(steps) >= 20 and 0.08 < sizes.max() < 0.09 and sizes.min() > 0.004
    gt = read_trajectory(shared_path("euroc_imu_gt", "V1_02_medium") / "groundtruth.csv")
    assert remove_position_jumps(gt)[1] == []


def test_the_rendered_attitude_stays_near_the_recorded_one() -> None:
    """Over a whole sequence the gyro's attitude, held over 1 s, stays within a degree of EuRoC's (V1_02:
    the ground truth's own biases; MH_03: a TUM file, the constant bias estimated)."""
    for sequence, name in (("V1_02_medium", "groundtruth.csv"), ("MH_03_medium", "groundtruth_tum.txt")):
        folder = shared_path("euroc_imu_gt", sequence)
        gt = read_trajectory(folder / name)
        t, gyro, _ = read_euroc_imu_csv(folder / "imu0.csv", policy="strict")
        out = gyro_consistent_attitude(gt, t, gyro)
        err = _angle_deg(out.R, interpolate_rotations(gt.t_ns, gt.R, out.t_ns))
        assert np.median(err) < 0.2 and err.max() < 1.0, (sequence, np.median(err), err.max())
