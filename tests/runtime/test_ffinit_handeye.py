"""Hand–eye alignment for calibration-withheld bring-up: recovers a withheld camera–IMU rotation
and the gyro bias from DA3-like relative rotations and real preintegration (paper Sec. IV-D)."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from runtime.ffinit.handeye import RotationWindow, estimate_handeye, validate_handeye
from runtime.ffinit.window import Rejection
from runtime.imu import Preintegrator

R_IC_TRUE = Rotation.from_euler("zyx", [88.0, -2.0, 1.5], degrees=True).as_matrix()


def _gyro(t: np.ndarray, seed: int, planar: bool = False) -> np.ndarray:
    rng = np.random.default_rng(seed)
    amp = rng.uniform(0.3, 0.8, 3)
    freq = rng.uniform(0.5, 2.0, 3)
    ph = rng.uniform(0, 2 * np.pi, 3)
    w = amp * np.sin(np.outer(t, freq) + ph)
    if planar:
        w[:, :2] = 0.0
    return w


def _window(seed: int, bg_true: np.ndarray, noise_deg: float, planar: bool = False) -> RotationWindow:
    rng = np.random.default_rng(100 + seed)
    t = np.arange(0.0, 0.85, 0.002)
    t_ns = np.round(t * 1e9).astype(np.int64)
    w_true = _gyro(t, seed, planar)
    acc = np.tile([0.0, 0.0, 9.81], (len(t), 1))
    pre_meas = Preintegrator(np.zeros(3), np.zeros(3))
    pre_true = Preintegrator(np.zeros(3), np.zeros(3))
    R_c, R_i, J = [], [], []
    for k in range(1, 5):
        t1 = int(k * 0.2e9)
        meas = pre_meas.integrate(t_ns, w_true + bg_true, acc, 0, t1)
        true = pre_true.integrate(t_ns, w_true, acc, 0, t1)
        noise = Rotation.from_rotvec(rng.normal(size=3) * np.radians(noise_deg) / np.sqrt(3)).as_matrix()
        R_c.append(R_IC_TRUE.T @ true.dR @ R_IC_TRUE @ noise)
        R_i.append(meas.dR)
        J.append(meas.J_R_bg)
    return RotationWindow(np.array(R_c), np.array(R_i), np.array(J), np.zeros(3))


def test_recovers_withheld_rotation_and_gyro_bias():
    bg = np.array([0.02, -0.015, 0.01])
    fit = [_window(s, bg, noise_deg=0.3) for s in range(4)]
    res = estimate_handeye(fit)
    assert not isinstance(res, Rejection), res
    err = np.degrees(Rotation.from_matrix(res.R_IC.T @ R_IC_TRUE).magnitude())
    assert err < 1.0
    np.testing.assert_allclose(res.bg, bg, atol=0.01)
    ok, rms = validate_handeye(res, _window(9, bg, noise_deg=0.3))
    assert ok and rms < 1.0


def test_noise_free_recovery_is_exact():
    bg = np.array([0.01, 0.0, -0.02])
    res = estimate_handeye([_window(s, bg, noise_deg=0.0) for s in range(3)])
    assert np.degrees(Rotation.from_matrix(res.R_IC.T @ R_IC_TRUE).magnitude()) < 1e-3
    np.testing.assert_allclose(res.bg, bg, atol=1e-4)
    assert res.rms_deg < 1e-3


def test_wrong_rotation_fails_validation():
    bg = np.zeros(3)
    res = estimate_handeye([_window(s, bg, noise_deg=0.0) for s in range(3)])
    res.R_IC = Rotation.from_euler("x", 5, degrees=True).as_matrix() @ res.R_IC
    ok, rms = validate_handeye(res, _window(7, bg, 0.0))
    assert not ok and rms > 1.0


def test_rotation_about_one_axis_is_rejected():
    res = estimate_handeye([_window(s, np.zeros(3), 0.0, planar=True) for s in range(3)])
    assert isinstance(res, Rejection) and res.reason == "handeye_degenerate_rotation"
