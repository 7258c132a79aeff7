"""EuRoC-trajectory mode (real IMU replayed against real ground truth), trajectory files, IMU drift."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.euroc import read_camera_timestamps, read_euroc_imu_csv
from drivers.sim.imu_synth import ImuErrorModel
from drivers.sim.motion import level_attitude
from drivers.sim.recording import SimConfig, SimRecording
from drivers.sim.rig import euroc_default_rig
from drivers.trajectory_files import read_trajectory
from runtime.errors import DataError, TrajectoryError
from runtime.events import Frame
from runtime.geometry.quaternion import rot_to_quat_xyzw
from tests.conftest import shared_path
from tools.benchmarks.real_imu_drift import drift_windows, fit_constant_biases


def _small_rig():
    rig = euroc_default_rig()
    return rig.replace(camera=rig.camera.scaled(0.25, 0.25))


@pytest.mark.parametrize("sequence", ["V1_02_medium", "MH_03_medium"])
def test_euroc_trajectory_mode_replays_the_real_imu(sequence: str) -> None:
    folder = shared_path("euroc_imu_gt", sequence)
    rec = SimRecording.from_euroc_imu_gt(
        folder, SimConfig(seconds=3.0, start_s=5.0, seed=1), rig=_small_rig()
    )
    t_all, gyro, accel = read_euroc_imu_csv(folder / "imu0.csv", policy="strict")
    gt = rec.groundtruth()
    # the real IMU rows inside the ground-truth window, untouched
    keep = (t_all >= gt.t_ns[0]) & (t_all <= gt.t_ns[-1])
    np.testing.assert_array_equal(rec.imu.t_ns, t_all[keep])
    np.testing.assert_array_equal(rec.imu.accel, accel[keep])
    # frames at the real camera stamps
    cams = read_camera_timestamps(folder / "cam0_timestamps.txt", policy="strict")
    assert np.isin(rec.frame_stamps_ns, cams).all() and 55 <= len(rec) <= 60
    assert rec.info["mode"] == "euroc-trajectory" and rec.info["sequence"] == sequence
    # the scene encloses the real trajectory and every pixel sees a surface lying on it
    frame, view = rec.render(len(rec) // 2)
    assert np.isfinite(view.depth).all()
    T = rec.gt_source.camera_pose(frame.t_ns)
    cam = rec.rig.camera
    u, v = np.meshgrid(np.arange(cam.width), np.arange(cam.height))
    p_C = cam.unproject(np.stack([u.ravel(), v.ravel()], 1).astype(float)) * view.depth.reshape(-1, 1)
    assert rec.scene.surface_distance(p_C @ T[:3, :3].T + T[:3, 3]).max() < 1e-3
    n_frames = sum(isinstance(e, Frame) for e in rec.events())
    assert n_frames == len(rec)


def test_imu_drift_is_zero_for_exact_synthetic_data_and_biases_are_recovered() -> None:
    cfg = SimConfig(
        preset="euroc",
        seconds=6.0,
        seed=2,
        imu_errors=ImuErrorModel(0.0, 0.0, 0.0, 0.0, initial_bg_sigma=0.01, initial_ba_sigma=0.1),
    )
    rec = SimRecording.from_preset(cfg, rig=_small_rig())
    imu, gt = rec.imu, rec.groundtruth()
    res = drift_windows(imu.t_ns, imu.gyro, imu.accel, gt, 1.0, 0.5, use_gt_bias=True)
    assert res["windows"] >= 9
    assert res["position_m"]["max"] < 1e-3 and res["orientation_deg"]["max"] < 1e-2
    zero = drift_windows(imu.t_ns, imu.gyro, imu.accel, gt, 1.0, 0.5, use_gt_bias=False)
    assert zero["position_m"]["median"] > 10 * res["position_m"]["median"]
    bg, ba = fit_constant_biases(imu.t_ns, imu.gyro, imu.accel, gt)
    np.testing.assert_allclose(bg, gt.bg[0], atol=2e-4)
    np.testing.assert_allclose(ba, gt.ba[0], atol=5e-3)


def test_euroc_trajectory_drift_with_ground_truth_biases() -> None:
    folder = shared_path("euroc_imu_gt", "V1_02_medium")
    gt = read_trajectory(folder / "groundtruth.csv")
    t, g, a = read_euroc_imu_csv(folder / "imu0.csv", policy="strict")
    gt = gt.subset(gt.t_ns < gt.t_ns[0] + int(12e9))
    res = drift_windows(t, g, a, gt, 1.0, 1.0, use_gt_bias=True)
    zero = drift_windows(t, g, a, gt, 1.0, 1.0, use_gt_bias=False)
    # real noise and small residual bias: centimetres, far below the zero-bias drift
    assert 0.001 < res["position_m"]["median"] < 0.1
    assert res["orientation_deg"]["median"] < 0.5 < zero["orientation_deg"]["median"]


def test_trajectory_file_with_synthetic_imu(tmp_path) -> None:
    t = 1_000_000_000 + np.arange(0, 2001) * 5_000_000  # 10 s at 200 Hz
    ts = (t - t[0]) * 1e-9
    lines = ["# t x y z qx qy qz qw"]
    for k in range(t.size):
        yaw = 0.2 * ts[k]
        # body x up, z forward (EuRoC mounting), heading yaw about world z
        q = rot_to_quat_xyzw(level_attitude(np.array([yaw]))[0])
        lines.append(
            f"{t[k] // 10**9}.{t[k] % 10**9:09d} {np.sin(ts[k]):.9f} {0.5 * ts[k]:.9f} 1.2 "
            f"{q[0]:.12f} {q[1]:.12f} {q[2]:.12f} {q[3]:.12f}"
        )
    path = tmp_path / "traj.tum"
    path.write_text("\n".join(lines) + "\n")
    cfg = SimConfig(seconds=None, seed=0, imu_errors=ImuErrorModel.noise_free())
    rec = SimRecording.from_trajectory(path, cfg, rig=_small_rig())
    assert rec.info["mode"] == "trajectory-spline"
    gt = rec.groundtruth()
    k = np.searchsorted(t, gt.t_ns[50:-50])
    assert np.abs(gt.p[50:-50] - np.stack([np.sin(ts[k]), 0.5 * ts[k], np.full(k.size, 1.2)], 1)).max() < 1e-3
    at_rest_norm = np.linalg.norm(rec.imu.accel, axis=1)
    assert np.all(np.abs(at_rest_norm - 9.81) < 1.5)


def test_replay_refuses_what_evaluation_tolerates(tmp_path) -> None:
    """The simulator interpolates its ground truth, so a repeated stamp (kept by evaluation, as evo
    does) is an error there; a decreasing stamp or a NaN IMU sample is an error everywhere."""
    rows = [f"{t:.2f} {t:.3f} 0 1 0 0 0 1" for t in np.arange(0.0, 3.0, 0.05)]
    repeated = tmp_path / "repeated.tum"
    repeated.write_text("\n".join(rows[:10] + [rows[9]] + rows[10:]) + "\n")
    assert read_trajectory(repeated).meta["repeated_stamps"] == 1
    with pytest.raises(TrajectoryError, match="repeated timestamp") as err:
        SimRecording.from_trajectory(repeated, SimConfig(seconds=None, seed=0), rig=_small_rig())
    assert err.value.line == 11
    backwards = tmp_path / "backwards.tum"
    backwards.write_text("1.0 0 0 0 0 0 0 1\n0.5 0 0 0 0 0 0 1\n")
    with pytest.raises(TrajectoryError, match="decreasing") as err:
        read_trajectory(backwards)
    assert err.value.line == 2
    imu = tmp_path / "imu.csv"
    imu.write_text("100,0,0,0,0,0,9.8\n200,0,nan,0,0,0,9.8\n")
    with pytest.raises(DataError, match="NaN") as err:
        read_euroc_imu_csv(imu, policy="strict")
    assert err.value.line == 2


def test_trajectory_file_with_real_imu_uses_the_camera_stamps_beside_it() -> None:
    folder = shared_path("euroc_imu_gt", "MH_03_medium")
    cfg = SimConfig(seconds=2.0, start_s=3.0, seed=0)
    rec = SimRecording.from_trajectory(
        folder / "groundtruth_tum.txt", cfg, rig=_small_rig(), imu_path=folder / "imu0.csv"
    )
    assert rec.info["mode"] == "euroc-trajectory"
    stamps = read_camera_timestamps(folder / "cam0_timestamps.txt", policy="strict")
    assert np.isin(rec.frame_stamps_ns, stamps).all()
    assert 38 <= len(rec) <= 40
    assert rec.groundtruth().v is None  # TUM ground truth: no velocity or biases
