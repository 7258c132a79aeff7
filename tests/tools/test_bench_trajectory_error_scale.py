"""The odometry-error scaling of `davio bench trajectory --error-scales`, against closed forms and the
evaluation module's ATE."""
from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from runtime.errors import ConfigError
from runtime.geometry import make_pose, so3_exp
from runtime.geometry.trajectory import PoseTrajectory
from runtime.mapping.windows import MappingWindow
from runtime.startup import Published
from tools.benchmarks.trajectory_error_scale import error_scaled_run, parse_error_scales, scale_pose_error
from tools.benchmarks.trajectory_inputs import MappingSlot, TrackingRun
from tools.benchmarks.trajectory_replay import odometry_poses
from tools.evaluation import ate

S = 1_000_000_000
OFFSET_NS = 30_000_000
"""The camera-to-IMU time offset of the synthetic rig: t_imu = t_cam + OFFSET_NS."""
T_IC = make_pose(so3_exp(np.array([1.2, -1.2, 1.2])), [0.05, -0.02, 0.01])
T_OW = {0: make_pose(so3_exp(np.array([0.0, 0.0, np.radians(40.0)])), [1.0, -2.0, 0.5]),
        1: make_pose(so3_exp(np.array([0.0, 0.0, np.radians(-75.0)])), [-3.0, 0.5, -0.2])}
"""Per filter segment, the odometry frame's pose in the truth's world frame: yaw and translation (both
gravity-aligned); a restart after a divergence starts a new odometry frame."""


def _true_T_WI(t_imu_ns: int) -> np.ndarray:
    t = t_imu_ns * 1e-9
    p = [2.0 * np.cos(0.4 * t), 1.5 * np.sin(0.4 * t), 0.3 * np.sin(0.8 * t)]
    R = so3_exp(np.array([0.0, 0.0, 0.4 * t + 0.1 * np.sin(t)])) @ so3_exp(np.array([0.05 * np.sin(t), 0, 0]))
    return make_pose(R, p)


def _camera_pose(t_cam_ns: int) -> np.ndarray:
    """The truth's T_WC of a frame stamped on the camera clock."""
    return _true_T_WI(t_cam_ns + OFFSET_NS) @ T_IC


def _error(t_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """The run's error at t: a position error (m, W) and a left rotation error (rad, W)."""
    t = t_ns * 1e-9
    return (np.array([0.03 * np.sin(0.7 * t), 0.02 * np.cos(0.3 * t), 0.01 * np.sin(t)]),
            np.array([0.002 * np.sin(t), 0.001 * np.cos(2 * t), 0.004 * np.sin(0.5 * t)]))


def _estimate_T_OI(t_imu_ns: int, segment: int) -> np.ndarray:
    T = _true_T_WI(t_imu_ns)
    e_p, e_r = _error(t_imu_ns)
    return T_OW[segment] @ make_pose(so3_exp(e_r) @ T[:3, :3], T[:3, 3] + e_p)


def _segment(i: int) -> int:
    return 0 if i < 150 else 1


def _run() -> TrackingRun:
    """300 published states at 10 Hz over two filter segments (150 each), and windows of 4 keyframes."""
    stamps = [k * S // 10 for k in range(300)]          # camera clock
    pub = []
    for i, t in enumerate(stamps):
        T = _estimate_T_OI(t + OFFSET_NS, _segment(i))
        pub.append(Published(t + OFFSET_NS, t, T[:3, :3], T[:3, 3], np.zeros(3), "test", 0, _segment(i)))
    slots = []
    for i in [*range(0, 130, 15), *range(150, 280, 15)]:
        t = np.array(stamps[i:i + 20:5], np.int64)
        frames = [SimpleNamespace(t_ns=int(x)) for x in t]
        T_OC = np.array([_estimate_T_OI(int(x) + OFFSET_NS, _segment(i)) @ T_IC for x in t])
        slots.append(MappingSlot(MappingWindow(len(slots), frames, T_OC, _segment(i)), (i, int(t[-1]))))
    return TrackingRun(pub, slots, len(slots), 0, 0, stamps[-1], 0, OFFSET_NS, len(stamps), 0.0)


def _rows(run: TrackingRun, segment: int | None) -> list[int]:
    return [i for i, p in enumerate(run.published) if segment is None or p.segment == segment]


def _truth(run: TrackingRun, segment: int | None = None) -> PoseTrajectory:
    """The true IMU poses at the published states' IMU stamps."""
    rows = _rows(run, segment)
    T = np.array([_true_T_WI(run.published[i].t_ns) for i in rows])
    return PoseTrajectory([run.published[i].t_ns for i in rows], T[:, :3, 3], T[:, :3, :3])


def _traj(run: TrackingRun, segment: int | None = None) -> PoseTrajectory:
    rows = _rows(run, segment)
    T = odometry_poses(run.published)[rows]
    return PoseTrajectory([run.published[i].t_ns for i in rows], T[:, :3, 3], T[:, :3, :3])


def test_scale_pose_error_closed_form():
    T_true = make_pose(so3_exp(np.array([0.3, -0.2, 1.0])), [1.0, 2.0, 3.0])
    phi = np.array([0.01, -0.02, 0.005])
    T_est = make_pose(so3_exp(phi) @ T_true[:3, :3], [1.1, 1.95, 3.0])
    np.testing.assert_allclose(scale_pose_error(T_est, T_true, 0.0), T_true, atol=1e-12)
    np.testing.assert_allclose(scale_pose_error(T_est, T_true, 1.0), T_est, atol=1e-12)
    T3 = scale_pose_error(T_est, T_true, 3.0)
    np.testing.assert_allclose(T3[:3, 3] - T_true[:3, 3], [0.3, -0.15, 0.0], atol=1e-12)
    np.testing.assert_allclose(T3[:3, :3], so3_exp(3.0 * phi) @ T_true[:3, :3], atol=1e-12)


def test_error_scaled_run_scales_the_ate_and_keeps_windows_consistent():
    """Two filter segments with their own odometry frames, a camera-to-IMU time offset: each segment's
    ATE (against the truth at the IMU stamps) and rotation errors scale by k."""
    run = _run()
    before = odometry_poses(run.published).copy()
    base = {s: ate(_traj(run, s), _truth(run, s), align_method="posyaw") for s in (0, 1)}
    assert all(0.01 < b.trans["rmse"] < 0.05 for b in base.values())

    same = error_scaled_run(run, _camera_pose, T_IC, 1.0)
    np.testing.assert_allclose(odometry_poses(same.published), before, atol=1e-9)
    np.testing.assert_allclose(np.array([s.window.T_OC for s in same.slots]),
                               np.array([s.window.T_OC for s in run.slots]), atol=1e-9)

    exact = error_scaled_run(run, _camera_pose, T_IC, 0.0)
    for seg in (0, 1):
        assert ate(_traj(exact, seg), _truth(exact, seg), align_method="posyaw").trans["rmse"] < 1e-9

    # The position + yaw fit that defines the error also aligns the scaled error best, so the ATE
    # (its own position + yaw alignment) and every rotation error scale exactly.
    for k in (0.5, 2.0, 4.0):
        scaled = error_scaled_run(run, _camera_pose, T_IC, k)
        for seg in (0, 1):
            r = ate(_traj(scaled, seg), _truth(scaled, seg), align_method="posyaw")
            assert r.trans["rmse"] == pytest.approx(k * base[seg].trans["rmse"], rel=1e-6)
            assert r.rot["max"] == pytest.approx(k * base[seg].rot["max"], rel=1e-4)

    # each window's camera poses are the scaled IMU poses of the same instants, through T_IC
    doubled = error_scaled_run(run, _camera_pose, T_IC, 2.0)
    by_t = {p.t_cam_ns: make_pose(p.R_OI, p.p_OI) for p in doubled.published}
    assert {s.window.segment for s in doubled.slots} == {0, 1}
    for slot in doubled.slots:
        for f, T_OC in zip(slot.window.frames, slot.window.T_OC, strict=True):
            np.testing.assert_allclose(T_OC, by_t[f.t_ns] @ T_IC, atol=1e-9)
        assert slot.applied is not None
    # the recorded run is left as it was, the schedule is kept
    np.testing.assert_array_equal(odometry_poses(run.published), before)
    assert [s.applied for s in doubled.slots] == [s.applied for s in run.slots]


def test_segments_without_a_position_fit():
    """A segment of one published state takes its yaw from its orientation and its translation from its
    position (its position error is then absorbed: the position stays its own, the rotation keeps only
    k x the tilt part of its error); a window of a segment that published nothing is left as recorded."""
    run = _run()
    run.published = run.published[:150] + [replace(run.published[200], segment=7)]
    lone = run.slots[-1]
    run.slots = run.slots[:3] + [replace(lone, window=replace(lone.window, segment=9))]
    scaled = error_scaled_run(run, _camera_pose, T_IC, 3.0)
    p_in, p_out = run.published[-1], scaled.published[-1]
    np.testing.assert_allclose(p_out.p_OI, p_in.p_OI, atol=1e-12)
    true_R = _true_T_WI(p_in.t_ns)[:3, :3]
    phi = _error(p_in.t_ns)[1]
    # the fitted yaw is O's up to the error's own yaw part, so the scaled pose stays within k |phi| of
    # the true one in O (not the 75 deg of O's yaw the fit removes)
    dR = (T_OW[1][:3, :3] @ true_R).T @ p_out.R_OI
    angle = np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1))
    assert angle <= 3.0 * np.linalg.norm(phi) + 1e-9
    tilt = np.hypot(phi[0], phi[1])
    assert angle >= 2.0 * tilt
    np.testing.assert_allclose(scaled.slots[-1].window.T_OC, lone.window.T_OC, atol=1e-12)


def test_error_scales_argument():
    assert parse_error_scales(None) == [] and parse_error_scales("") == []
    assert parse_error_scales("0.5, 2,4") == [0.5, 2.0, 4.0]
    assert parse_error_scales("-0,1") == [0.0, 1.0]
    for bad, why in (("two", "not a number"), ("-1", "-1 must be"), ("nan", "nan must be"),
                     ("0.5,", "empty entry"), ("1,2,1", "1 is given twice")):
        with pytest.raises(ConfigError, match=f"--error-scales: .*{why}"):
            parse_error_scales(bad)
    with pytest.raises(ConfigError, match="error scale"):
        error_scaled_run(_run(), _camera_pose, T_IC, -0.5)


def test_bench_rows_replay_the_scaled_run(monkeypatch):
    """`error_scale_rows` hands the mapper the scaled run and scores it against the truth; at k = 0 (an
    exact odometry) no ratio is reported."""
    from tools.benchmarks import trajectory as bench

    run = _run()
    seen = []

    def fake_ablation(ab, scaled_run, ctx):
        seen.append((ab.key, scaled_run))
        return {"final_ate_m": 0.01, "causal_ate_m": 0.02, "graph": {}}, None

    monkeypatch.setattr(bench, "run_ablation", fake_ablation)
    ctx = {"truth": SimpleNamespace(camera_pose=_camera_pose), "gt": _truth(run),
           "idx": np.array(_rows(run, 1))}                 # the scored (last) segment
    rows = bench.error_scale_rows(run, SimpleNamespace(rig=SimpleNamespace(T_IC=T_IC)), ctx, [0.0, 1.0, 3.0])
    assert [key for key, _ in seen] == ["davio"] * 3
    base = ate(_traj(run, 1), _truth(run, 1), align_method="se3").trans["rmse"]
    assert rows["0"]["odometry_ate_m"] < 1e-6 and rows["0"]["final_ratio"] is None
    assert rows["1"]["odometry_ate_m"] == pytest.approx(base, rel=1e-9)
    assert rows["1"]["final_ratio"] == pytest.approx(0.01 / base)
    assert rows["1"]["causal_ratio"] == pytest.approx(0.02 / base)
    assert rows["3"]["odometry_ate_m"] == pytest.approx(3 * base, rel=0.05)
    np.testing.assert_allclose(odometry_poses(seen[2][1].published),
                               odometry_poses(error_scaled_run(run, _camera_pose, T_IC, 3.0).published))
