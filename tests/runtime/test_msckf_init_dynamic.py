"""Dynamic initializer on synthetic noiseless features + IMU with analytic derivatives."""

from __future__ import annotations

import numpy as np
import pytest

from calib import Pinhole
from runtime.errors import ConfigError
from runtime.events import ImuSample
from runtime.geometry import so3_exp, so3_right_jacobian
from runtime.msckf.init_common import ERROR_STATE_ORDER, gravity_angle_deg
from runtime.msckf.init_dynamic import DynamicInitConfig, DynamicInitializer, min_quadratic_on_sphere

G0 = 9.81
CAM = Pinhole(640, 480, 400.0, 400.0, 319.5, 239.5)
# EuRoC-like extrinsics: camera z along IMU z, x/y swapped
R_IC = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]) @ so3_exp(
    np.array([0.01, -0.02, 0.015])
)
T_IC = np.eye(4)
T_IC[:3, :3] = R_IC
T_IC[:3, 3] = [-0.02, -0.06, 0.01]
# base attitude: the camera looks along world +x, its y axis down
R_WC0 = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
R_BASE = R_WC0 @ R_IC.T


class Motion:
    """p(t), R(t) = R_BASE Exp(phi(t)) with closed-form derivatives; 'kind' selects the case."""

    def __init__(self, kind: str) -> None:
        self.kind = kind

    def phi(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        if self.kind == "static":
            return np.zeros(3), np.zeros(3)
        a = np.array([0.15, 0.12, 0.2])
        w = np.array([1.3, 1.7, 0.9])
        return a * np.sin(w * t), a * w * np.cos(w * t)

    def pos(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self.kind in ("static", "rotation"):
            return np.zeros(3), np.zeros(3), np.zeros(3)
        A = np.array([0.6, 0.5, 0.3])
        w = np.array([1.1, 1.4, 1.9])
        ph = np.array([0.0, 0.5, 1.0])
        return (A * np.sin(w * t + ph), A * w * np.cos(w * t + ph), -A * w * w * np.sin(w * t + ph))

    def state(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """R_WI, p_WI, v_WI, gyro (body rad/s), accel (specific force, body)."""
        phi, dphi = self.phi(t)
        R = R_BASE @ so3_exp(phi)
        p, v, a = self.pos(t)
        omega = so3_right_jacobian(phi) @ dphi
        f = R.T @ (a + np.array([0.0, 0.0, G0]))
        return R, p, v, omega, f


def landmarks(seed: int = 0, n: int = 120) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.c_[rng.uniform(4.0, 8.0, n), rng.uniform(-3.0, 3.0, n), rng.uniform(-2.0, 2.0, n)]


def feed(
    init: DynamicInitializer,
    motion: Motion,
    duration: float = 2.5,
    imu_hz: float = 1000.0,
    cam_hz: float = 20.0,
    t0: float = 1.0,
) -> float:
    """Feed IMU and camera from t0 (s) on; returns the last camera time (s)."""
    L = landmarks()
    n_imu = int(duration * imu_hz) + 1
    for i in range(n_imu):
        t = t0 + i / imu_hz
        _, _, _, w, f = motion.state(t)
        init.feed_imu(ImuSample(int(round(t * 1e9)), w, f))
    n_cam = int((duration - 0.01) * cam_hz) + 1
    t = t0
    for j in range(n_cam):
        t = t0 + j / cam_hz
        R, p, _, _, _ = motion.state(t)
        R_WC = R @ R_IC
        p_WC = p + R @ T_IC[:3, 3]
        p_C = (L - p_WC) @ R_WC
        uv = CAM.project(p_C)
        ok = (p_C[:, 2] > 0.5) & np.all(np.isfinite(uv), axis=1)
        ok &= (uv[:, 0] > 0) & (uv[:, 0] < 639) & (uv[:, 1] > 0) & (uv[:, 1] < 479)
        init.feed_tracks(int(round(t * 1e9)), np.flatnonzero(ok), uv[ok])
    return t


@pytest.mark.slow
def test_recovers_velocity_gravity_and_orientation() -> None:
    motion = Motion("general")
    init = DynamicInitializer(CAM, T_IC, DynamicInitConfig())
    t_last = feed(init, motion)
    res = init.try_initialize()
    assert res is not None, init.last_reason
    assert res.source == "dynamic" and res.t_ns == int(round(t_last * 1e9))
    R, _, v, _, _ = motion.state(t_last)
    # gravity direction (roll/pitch) and body-frame velocity are yaw-independent
    assert gravity_angle_deg(res.gravity_in_imu, R[2, :]) < 0.01
    np.testing.assert_allclose(res.R_OI.T @ res.v_OI, R.T @ v, atol=2e-3)
    # the linear stage alone is already accurate: gravity in the first keyframe frame
    R0, _, v0, _, _ = motion.state(t_last - 2.0)
    g_I0 = R0.T @ np.array([0.0, 0.0, -G0])
    assert np.linalg.norm(res.info["g_I0_linear"]) == pytest.approx(G0, rel=1e-9)
    assert gravity_angle_deg(res.info["g_I0_linear"], g_I0) < 0.05
    np.testing.assert_allclose(res.info["v_I0_linear"], R0.T @ v0, atol=5e-3)
    # relative pose over the window: position change in O matches the truth's length
    assert res.info["reprojection_rms_px"] < 0.05
    np.testing.assert_allclose(res.bg, 0.0, atol=2e-3)
    np.testing.assert_allclose(res.ba, 0.0, atol=0.05)
    assert res.cov.shape == (15, 15) and len(ERROR_STATE_ORDER) == 5
    assert np.all(np.linalg.eigvalsh(res.cov) > 0)
    np.testing.assert_allclose(res.R_OI @ res.R_OI.T, np.eye(3), atol=1e-10)


def feed_noisy(
    init: DynamicInitializer,
    motion: Motion,
    seed: int,
    bg: np.ndarray,
    ba: np.ndarray,
    px: float = 0.5,
    imu_hz: float = 200.0,
    duration: float = 2.5,
) -> float:
    """Like feed() with EuRoC-level white IMU noise, constant biases and pixel noise; last camera time (s)."""
    rng = np.random.default_rng(seed)
    t0 = 1.0
    L = landmarks(seed)
    gd, ad = 1.6968e-4, 2.0e-3  # continuous densities; discrete std = density * sqrt(rate)
    for i in range(int(duration * imu_hz) + 1):
        t = t0 + i / imu_hz
        _, _, _, w, f = motion.state(t)
        w = w + bg + gd * np.sqrt(imu_hz) * rng.standard_normal(3)
        f = f + ba + ad * np.sqrt(imu_hz) * rng.standard_normal(3)
        init.feed_imu(ImuSample(int(round(t * 1e9)), w, f))
    t = t0
    for j in range(int((duration - 0.01) * 20) + 1):
        t = t0 + j / 20
        R, p, _, _, _ = motion.state(t)
        p_C = (L - (p + R @ T_IC[:3, 3])) @ (R @ R_IC)
        uv = CAM.project(p_C)
        ok = (p_C[:, 2] > 0.5) & np.all(np.isfinite(uv), axis=1)
        ok &= (uv[:, 0] > 0) & (uv[:, 0] < 639) & (uv[:, 1] > 0) & (uv[:, 1] < 479)
        init.feed_tracks(
            int(round(t * 1e9)), np.flatnonzero(ok), uv[ok] + px * rng.standard_normal((ok.sum(), 2))
        )
    return t


@pytest.mark.slow
def test_noisy_measurements_refinement_recovers_gyro_bias_and_velocity() -> None:
    motion = Motion("general")
    bg = np.array([0.003, -0.002, 0.004])
    init = DynamicInitializer(CAM, T_IC, DynamicInitConfig())
    t_last = feed_noisy(init, motion, seed=2, bg=bg, ba=np.array([0.05, -0.03, 0.04]))
    res = init.try_initialize()
    assert res is not None, init.last_reason
    R, _, v, _, _ = motion.state(t_last)
    R0, _, v0, _, _ = motion.state(t_last - 2.0)
    assert gravity_angle_deg(res.gravity_in_imu, R[2, :]) < 1.0
    v_err = np.linalg.norm(res.R_OI.T @ res.v_OI - R.T @ v)
    assert v_err < 0.05
    # the linear stage assumed zero gyro bias; the refinement estimates it and beats the linear velocity
    np.testing.assert_allclose(res.bg, bg, atol=1.5e-3)
    assert v_err < np.linalg.norm(res.info["v_I0_linear"] - R0.T @ v0)
    assert 0.3 < res.info["reprojection_rms_px"] < 0.7  # about the 0.5 px noise
    # the reported (inflated) velocity std covers the actual error
    assert v_err < 3.0 * np.sqrt(np.trace(res.cov[6:9, 6:9]))


@pytest.mark.slow
def test_both_refinement_solvers_reach_the_same_state_on_a_noisy_window() -> None:
    """Levenberg-Marquardt with the analytic Jacobian (the default) and scipy's trust-region solver with
    finite differences (the reference) end on the same window's solution: far closer to each other than
    either is to the truth, and with the same covariance to a few percent."""
    motion = Motion("general")
    out = {}
    for solver in ("lm", "scipy-fd"):
        init = DynamicInitializer(CAM, T_IC, DynamicInitConfig(mle_solver=solver))
        t_last = feed_noisy(init, motion, seed=5, bg=np.array([0.002, 0.003, -0.001]),
                            ba=np.array([-0.04, 0.02, 0.05]))
        out[solver] = init.try_initialize()
        assert out[solver] is not None, init.last_reason
    a, b = out["lm"], out["scipy-fd"]
    R, _, v, _, _ = motion.state(t_last)
    v_err = np.linalg.norm(a.R_OI.T @ a.v_OI - R.T @ v)
    assert np.linalg.norm(a.v_OI - b.v_OI) < 0.1 * v_err + 1e-3
    assert gravity_angle_deg(a.gravity_in_imu, b.gravity_in_imu) < 0.02
    np.testing.assert_allclose(a.bg, b.bg, atol=1e-4)
    np.testing.assert_allclose(np.sqrt(np.diag(a.cov)), np.sqrt(np.diag(b.cov)), rtol=0.05)
    assert a.info["reprojection_rms_px"] == pytest.approx(b.info["reprojection_rms_px"], rel=0.01)


@pytest.mark.parametrize("solver", ["lm", "scipy-fd"])
def test_a_refinement_cut_short_by_its_budget_is_refused(solver: str) -> None:
    """As OpenVINS refuses a window whose Ceres solve did not converge: the same window is accepted when
    its refinement converges and refused (mle_not_converged) when mle_max_iterations stops it first."""
    motion = Motion("general")
    budgets = {"lm": (20, 3), "scipy-fd": (60, 3)}[solver]
    out = []
    for budget in budgets:
        init = DynamicInitializer(CAM, T_IC, DynamicInitConfig(mle_solver=solver, mle_max_iterations=budget))
        feed_noisy(init, motion, seed=2, bg=np.array([0.003, -0.002, 0.004]),
                   ba=np.array([0.05, -0.03, 0.04]))
        out.append((init.try_initialize(), init))
    (full, init_full), (cut, init_cut) = out
    assert full is not None, init_full.last_reason
    assert full.info["mle_converged"] and full.info["mle_evaluations"] > 3
    assert cut is None and init_cut.log.last.code == "mle_not_converged"
    assert "did not converge in 3 evaluations (mle_max_iterations 3)" in init_cut.last_reason


def test_out_of_order_frames_are_counted_and_reset_clears() -> None:
    init = DynamicInitializer(CAM, T_IC)
    init.feed_tracks(100, np.arange(3), np.full((3, 2), 100.0))
    init.feed_tracks(100, np.arange(3), np.full((3, 2), 100.0))
    assert init.report()["frames_dropped_out_of_order"] == 1
    init.feed_imu(ImuSample(100, np.zeros(3), np.array([0.0, 0.0, G0])))
    init.reset()
    assert len(init.tracks.frames) == 0 and len(init.imu) == 0


@pytest.mark.parametrize(
    "kind, code", [("rotation", "insufficient_parallax"), ("static", "insufficient_rotation")]
)
def test_rejects_degenerate_motion(kind: str, code: str) -> None:
    init = DynamicInitializer(CAM, T_IC, DynamicInitConfig())
    feed(init, Motion(kind), imu_hz=200.0)
    assert init.try_initialize() is None
    assert init.log.last.code == code, init.last_reason
    assert code in init.report()["rejections"]


def test_rejects_without_enough_data() -> None:
    init = DynamicInitializer(CAM, T_IC)
    assert init.try_initialize() is None and init.log.last.code == "no_frames"
    feed(init, Motion("general"), duration=0.2, imu_hz=200.0)
    assert init.try_initialize() is None and init.log.last.code == "few_frames"
    with pytest.raises(ConfigError):
        DynamicInitConfig(num_pose=2)
    with pytest.raises(ConfigError, match="mle_max_iterations must be 0 .* or >= 2"):
        DynamicInitConfig(mle_max_iterations=1)
    assert DynamicInitConfig(mle_max_iterations=0).mle_max_iterations == 0
    with pytest.raises(ConfigError):
        DynamicInitializer(CAM, np.eye(3))


def test_min_quadratic_on_sphere_matches_brute_force() -> None:
    rng = np.random.default_rng(0)
    for _ in range(20):
        B = rng.standard_normal((6, 3))
        M = B.T @ B
        m = rng.standard_normal(3) * rng.uniform(0.01, 10)
        g = min_quadratic_on_sphere(M, m, 9.81)
        assert np.linalg.norm(g) == pytest.approx(9.81, rel=1e-9)
        # dense sampling of the sphere never beats it
        u = rng.standard_normal((20000, 3))
        u = 9.81 * u / np.linalg.norm(u, axis=1, keepdims=True)

        def cost(x: np.ndarray, M: np.ndarray = M, m: np.ndarray = m) -> np.ndarray:
            x = np.atleast_2d(x)
            return np.einsum("ni,ij,nj->n", x, M, x) - 2 * x @ m

        assert cost(g)[0] <= cost(u).min() + 1e-9
