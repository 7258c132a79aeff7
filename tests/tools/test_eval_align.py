"""Alignment and ATE on synthetic trajectories with known transforms (closed-form expectations)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from runtime.errors import TrajectoryError
from runtime.geometry.trajectory import PoseTrajectory
from tools.evaluation import (
    align,
    associate,
    ate,
    ate_degenerate_truth,
    posyaw,
    rpe,
    truth_is_degenerate,
    umeyama,
)


def helix(n: int = 200, seed: int = 0) -> PoseTrajectory:
    rng = np.random.default_rng(seed)
    s = np.linspace(0, 4 * np.pi, n)
    p = np.stack([3 * np.cos(s), 2 * np.sin(s), 0.3 * s], axis=1)
    R = Rotation.from_rotvec(rng.normal(size=(n, 3)) * 0.5).as_matrix()
    t_ns = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 50_000_000
    return PoseTrajectory(t_ns, p, R)


def transformed(traj: PoseTrajectory, R: np.ndarray, t: np.ndarray, s: float = 1.0) -> PoseTrajectory:
    return PoseTrajectory(traj.t_ns, s * traj.p @ R.T + t, R @ traj.R)


def rot_z(yaw: float) -> np.ndarray:
    return Rotation.from_euler("z", yaw).as_matrix()


@pytest.mark.parametrize("method, scale", [("se3", 1.0), ("sim3", 0.37), ("posyaw", 1.0)])
def test_known_transform_is_recovered_exactly(method: str, scale: float) -> None:
    ref = helix()
    # est = inverse transform of ref: aligning est must give ref back
    R = rot_z(0.8) if method == "posyaw" else Rotation.from_rotvec([0.3, -1.1, 0.4]).as_matrix()
    t = np.array([4.0, -2.0, 1.5])
    est = transformed(ref, R.T, -R.T @ t / scale, 1.0 / scale)
    res = ate(est, ref, method)
    assert res.rmse < 1e-9 and res.rot["max"] < 1e-6
    np.testing.assert_allclose(res.alignment.R, R, atol=1e-9)
    np.testing.assert_allclose(res.alignment.t, t, atol=1e-9)
    assert res.alignment.s == pytest.approx(scale, rel=1e-9)


def test_posyaw_cannot_fix_tilt_but_se3_can() -> None:
    ref = helix()
    est = transformed(ref, Rotation.from_euler("x", 0.2).as_matrix(), np.zeros(3))
    assert ate(est, ref, "se3").rmse < 1e-9
    assert ate(est, ref, "posyaw").rmse > 0.1


def test_umeyama_against_scipy_kabsch_with_noise() -> None:
    rng = np.random.default_rng(1)
    src = rng.normal(size=(100, 3))
    R_true = Rotation.from_rotvec([0.5, 0.2, -0.7]).as_matrix()
    dst = src @ R_true.T + [1.0, 2.0, 3.0] + rng.normal(scale=0.05, size=src.shape)
    R, t, s = umeyama(src, dst)
    R_scipy, _ = Rotation.align_vectors(dst - dst.mean(0), src - src.mean(0))
    np.testing.assert_allclose(R, R_scipy.as_matrix(), atol=1e-10)
    np.testing.assert_allclose(t, dst.mean(0) - R @ src.mean(0), atol=1e-12)
    assert s == 1.0


def test_posyaw_closed_form_is_the_least_squares_minimum() -> None:
    rng = np.random.default_rng(2)
    src = rng.normal(size=(60, 3)) * [3, 3, 0.5]
    dst = src @ rot_z(-2.5).T + [0.2, -0.3, 0.1] + rng.normal(scale=0.1, size=src.shape)
    R, t = posyaw(src, dst)
    cost = lambda R_, t_: np.sum((dst - src @ R_.T - t_) ** 2)  # noqa: E731
    best = cost(R, t)
    for yaw in np.linspace(-np.pi, np.pi, 2001):
        Rz = rot_z(yaw)
        assert cost(Rz, dst.mean(0) - Rz @ src.mean(0)) >= best - 1e-9
    assert np.allclose(R[2], [0, 0, 1]) and np.allclose(R[:, 2], [0, 0, 1])


def test_degenerate_configurations_raise() -> None:
    line = np.stack([np.linspace(0, 1, 10), np.zeros(10), np.zeros(10)], axis=1)
    with pytest.raises(TrajectoryError, match="degenerate"):
        umeyama(line, line)
    with pytest.raises(TrajectoryError, match="at least 3"):
        umeyama(line[:2], line[:2])
    vertical = np.stack([np.zeros(10), np.zeros(10), np.linspace(0, 1, 10)], axis=1)
    with pytest.raises(TrajectoryError, match="yaw"):
        posyaw(vertical, vertical)
    traj = helix(10)
    with pytest.raises(TrajectoryError, match="unknown alignment"):
        align(traj, traj, "scale")
    with pytest.raises(TrajectoryError, match="associated"):
        align(traj, traj.subset(np.arange(5)), "se3")


def test_association_tolerance_offset_and_one_to_one() -> None:
    ref = helix(100)
    est = ref.subset(np.arange(0, 100, 3))
    est = PoseTrajectory(est.t_ns + 4_000_000, est.p, est.R)          # 4 ms late
    e, r = associate(est, ref, max_diff_s=0.005)
    assert len(e) == len(est) and np.all(r.t_ns == est.t_ns - 4_000_000)
    with pytest.raises(TrajectoryError, match="no matching stamps"):
        associate(est, ref, max_diff_s=0.003)
    e, r = associate(est, ref, max_diff_s=0.001, offset_s=-0.004)
    assert len(e) == len(est)
    # a repeated estimate stamp reuses one reference pose unless one_to_one
    stamps = np.r_[ref.t_ns[:3], ref.t_ns[2], ref.t_ns[3:6]]
    rep = PoseTrajectory(stamps, np.zeros((7, 3)), np.tile(np.eye(3), (7, 1, 1)))
    e, r = associate(rep, ref)
    assert len(e) == 7 and r.t_ns[2] == r.t_ns[3]
    e, r = associate(rep, ref, one_to_one=True)
    assert len(e) == 6 and np.all(np.diff(r.t_ns) > 0)


def test_rpe_zero_for_rigidly_moved_estimate_and_scale_sensitive() -> None:
    ref = helix()
    est = transformed(ref, Rotation.from_rotvec([0.1, 0.2, 0.3]).as_matrix(), np.array([5.0, 1.0, 0.0]))
    res = rpe(est, ref, delta=3)
    assert res.rmse < 1e-9 and res.rot["max"] < 1e-6
    scaled = transformed(ref, np.eye(3), np.zeros(3), 2.0)
    step = np.linalg.norm(ref.p[3] - ref.p[0])
    res = rpe(scaled, ref, delta=3)
    # each relative translation doubles: |t(E)| equals the reference step length
    assert res.trans_err_m[0] == pytest.approx(step, rel=1e-9)
    assert rpe(scaled, ref, delta=3, align_method="sim3").rmse < 1e-9
    with pytest.raises(TrajectoryError, match="delta unit"):
        rpe(est, ref, delta=1, delta_unit="s")


def test_a_truth_that_turns_in_place_is_scored_by_the_estimate_spread_or_position_and_yaw() -> None:
    """A static truth fixes no rotation: se3 refuses it, and the ATE is the estimate's RMS spread about its
    mean (closed form); a truth moving straight along x fixes yaw and translation (posyaw), so an estimate
    yawed and shifted from it scores zero; a truth that moves only vertically is compared at the same
    stamps after a translation."""
    n = 50
    t_ns = 1_000_000_000 + np.arange(n, dtype=np.int64) * 50_000_000
    yaw = np.linspace(0.0, 3.0, n)
    R = Rotation.from_euler("z", yaw[:, None]).as_matrix()
    static = PoseTrajectory(t_ns, np.zeros((n, 3)), R)
    with pytest.raises(TrajectoryError):
        ate(static, static, align_method="se3")
    rng = np.random.default_rng(3)
    drift = np.cumsum(rng.normal(scale=0.01, size=(n, 3)), axis=0) + np.array([5.0, -2.0, 1.0])
    est = PoseTrajectory(t_ns, drift, R)
    spread = np.sqrt(np.mean(np.sum((drift - drift.mean(axis=0)) ** 2, axis=1)))
    assert ate_degenerate_truth(est, static).trans["rmse"] == pytest.approx(spread, rel=1e-9)
    line = PoseTrajectory(t_ns, np.c_[np.linspace(0, 2, n), np.zeros(n), np.zeros(n)], R)
    moved = transformed(line, rot_z(0.7), np.array([1.0, 2.0, 0.5]))
    assert ate_degenerate_truth(moved, line).trans["rmse"] == pytest.approx(0.0, abs=1e-9)
    # a truth that only climbs fixes no yaw either: a shifted exact estimate scores zero, a noisy one the
    # RMS of its error about the mean error
    climb = PoseTrajectory(t_ns, np.c_[np.zeros(n), np.zeros(n), np.linspace(0, 2, n)], R)
    assert truth_is_degenerate(climb, climb) and truth_is_degenerate(est, static)
    circle = PoseTrajectory(t_ns, np.c_[np.cos(yaw), np.sin(yaw), np.zeros(n)], R)
    assert not truth_is_degenerate(line, circle) and not truth_is_degenerate(circle, circle)
    shifted = PoseTrajectory(t_ns, climb.p + np.array([0.3, -0.2, 1.0]), R)
    assert ate_degenerate_truth(shifted, climb).trans["rmse"] == pytest.approx(0.0, abs=1e-9)
    noisy = PoseTrajectory(t_ns, climb.p + drift, R)
    assert ate_degenerate_truth(noisy, climb).trans["rmse"] == pytest.approx(spread, rel=1e-9)
