"""The odometry-error scaling of `davio bench trajectory --error-scales`, against closed forms and the
evaluation module's ATE."""
from __future__ import annotations

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
T_IC = make_pose(so3_exp(np.array([1.2, -1.2, 1.2])), [0.05, -0.02, 0.01])
T_OW = make_pose(so3_exp(np.array([0.0, 0.0, np.radians(40.0)])), [1.0, -2.0, 0.5])
"""The odometry frame's pose in the truth's world frame: yaw and translation (both gravity-aligned)."""


def _true_T_WI(t_ns: int) -> np.ndarray:
    t = t_ns * 1e-9
    p = [2.0 * np.cos(0.4 * t), 1.5 * np.sin(0.4 * t), 0.3 * np.sin(0.8 * t)]
    R = so3_exp(np.array([0.0, 0.0, 0.4 * t + 0.1 * np.sin(t)])) @ so3_exp(np.array([0.05 * np.sin(t), 0, 0]))
    return make_pose(R, p)


def _camera_pose(t_ns: int) -> np.ndarray:
    return _true_T_WI(t_ns) @ T_IC


def _error(t_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """The run's error at t: a position error (m, W) and a left rotation error (rad, W)."""
    t = t_ns * 1e-9
    return (np.array([0.03 * np.sin(0.7 * t), 0.02 * np.cos(0.3 * t), 0.01 * np.sin(t)]),
            np.array([0.002 * np.sin(t), 0.001 * np.cos(2 * t), 0.004 * np.sin(0.5 * t)]))


def _estimate_T_OI(t_ns: int) -> np.ndarray:
    T = _true_T_WI(t_ns)
    e_p, e_r = _error(t_ns)
    return T_OW @ make_pose(so3_exp(e_r) @ T[:3, :3], T[:3, 3] + e_p)


def _run() -> TrackingRun:
    stamps = [k * S // 10 for k in range(300)]
    pub = []
    for t in stamps:
        T = _estimate_T_OI(t)
        pub.append(Published(t, t, T[:3, :3], T[:3, 3], np.zeros(3), "test", 0, 0))
    slots = []
    for i in range(0, 280, 15):
        t = np.array(stamps[i:i + 20:5], np.int64)
        frames = [SimpleNamespace(t_ns=int(x)) for x in t]
        T_OC = np.array([_estimate_T_OI(int(x)) @ T_IC for x in t])
        slots.append(MappingSlot(MappingWindow(len(slots), frames, T_OC, 0), (i, int(t[-1]))))
    return TrackingRun(pub, slots, len(slots), 0, 0, stamps[-1], 0, 0, len(stamps), 0.0)


def _truth(run: TrackingRun) -> PoseTrajectory:
    T = np.array([_true_T_WI(p.t_ns) for p in run.published])
    return PoseTrajectory([p.t_ns for p in run.published], T[:, :3, 3], T[:, :3, :3])


def _traj(run: TrackingRun) -> PoseTrajectory:
    T = odometry_poses(run.published)
    return PoseTrajectory([p.t_ns for p in run.published], T[:, :3, 3], T[:, :3, :3])


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
    run = _run()
    before = odometry_poses(run.published).copy()
    truth = _truth(run)
    base = ate(_traj(run), truth, align_method="posyaw")
    assert 0.01 < base.trans["rmse"] < 0.05

    same = error_scaled_run(run, _camera_pose, T_IC, 1.0)
    np.testing.assert_allclose(odometry_poses(same.published), before, atol=1e-9)
    np.testing.assert_allclose(np.array([s.window.T_OC for s in same.slots]),
                               np.array([s.window.T_OC for s in run.slots]), atol=1e-9)

    exact = error_scaled_run(run, _camera_pose, T_IC, 0.0)
    assert ate(_traj(exact), truth, align_method="posyaw").trans["rmse"] < 1e-9

    # The position + yaw fit that defines the error also aligns the doubled error best, so the ATE
    # (its own position + yaw alignment) and every rotation error double exactly.
    for k in (0.5, 2.0, 4.0):
        r = ate(_traj(error_scaled_run(run, _camera_pose, T_IC, k)), truth, align_method="posyaw")
        assert r.trans["rmse"] == pytest.approx(k * base.trans["rmse"], rel=1e-6)
        assert r.rot["max"] == pytest.approx(k * base.rot["max"], rel=1e-4)

    # each window's camera poses are the scaled IMU poses of the same instants, through T_IC
    doubled = error_scaled_run(run, _camera_pose, T_IC, 2.0)
    by_t = {p.t_cam_ns: make_pose(p.R_OI, p.p_OI) for p in doubled.published}
    for slot in doubled.slots:
        for f, T_OC in zip(slot.window.frames, slot.window.T_OC, strict=True):
            np.testing.assert_allclose(T_OC, by_t[f.t_ns] @ T_IC, atol=1e-9)
        assert slot.applied is not None
    # the recorded run is left as it was, the schedule is kept
    np.testing.assert_array_equal(odometry_poses(run.published), before)
    assert [s.applied for s in doubled.slots] == [s.applied for s in run.slots]


def test_error_scales_argument():
    assert parse_error_scales(None) == [] and parse_error_scales("") == []
    assert parse_error_scales("0.5, 2,4") == [0.5, 2.0, 4.0]
    for bad in ("two", "-1", "nan"):
        with pytest.raises(ConfigError, match="--error-scales"):
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
           "idx": np.arange(len(run.published))}
    rows = bench.error_scale_rows(run, SimpleNamespace(rig=SimpleNamespace(T_IC=T_IC)), ctx, [0.0, 1.0, 3.0])
    assert [key for key, _ in seen] == ["davio"] * 3
    base = ate(_traj(run), _truth(run), align_method="se3").trans["rmse"]
    assert rows["0"]["odometry_ate_m"] < 1e-6 and rows["0"]["final_ratio"] is None
    assert rows["1"]["odometry_ate_m"] == pytest.approx(base, rel=1e-9)
    assert rows["1"]["final_ratio"] == pytest.approx(0.01 / base)
    assert rows["1"]["causal_ratio"] == pytest.approx(0.02 / base)
    assert rows["3"]["odometry_ate_m"] == pytest.approx(3 * base, rel=0.05)
    np.testing.assert_allclose(odometry_poses(seen[2][1].published),
                               odometry_poses(error_scaled_run(run, _camera_pose, T_IC, 3.0).published))
