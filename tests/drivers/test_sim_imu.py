"""IMU synthesis: noise-free samples integrate back onto the spline; noise and bias statistics."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.sim.dead_reckoning import integrate_imu
from drivers.sim.imu_synth import ImuErrorModel, imu_stamps, synthesize_imu
from drivers.sim.motion import G0, preset_spline
from runtime.geometry.so3 import so3_log


@pytest.mark.parametrize("preset", ["euroc", "aggressive"])
def test_noise_free_imu_integrates_onto_the_spline(preset: str) -> None:
    s = preset_spline(preset, 8.0, seed=3)
    t = imu_stamps(s.t0_ns, s.t0_ns + int(8e9), 200.0)
    imu = synthesize_imu(s, t, ImuErrorModel.noise_free())
    truth = s.sample(t)
    for k0 in range(0, t.size - 201, 150):  # 1 s windows from the true state
        sl = slice(k0, k0 + 201)
        R, p, v = integrate_imu(t[sl], imu.gyro[sl], imu.accel[sl], truth.R[k0], truth.p[k0], truth.v[k0])
        assert np.linalg.norm(p - truth.p[sl], axis=1).max() < 1e-3  # sub-millimetre over 1 s
        assert np.linalg.norm(v[-1] - truth.v[k0 + 200]) < 2e-3
        assert np.linalg.norm(so3_log(truth.R[k0 + 200].T @ R[-1])) < 5e-5  # 0.003 deg


def test_at_rest_the_accelerometer_reads_gravity_up() -> None:
    s = preset_spline("euroc", 3.0, seed=0)  # 2 s on the ground
    t = imu_stamps(s.t0_ns, s.t0_ns + int(1.5e9), 200.0)
    imu = synthesize_imu(s, t, ImuErrorModel.noise_free())
    np.testing.assert_allclose(imu.gyro, 0.0, atol=1e-12)
    # body x is up when level (EuRoC mounting): specific force +g along x_I
    np.testing.assert_allclose(imu.accel, np.tile([G0, 0.0, 0.0], (t.size, 1)), atol=1e-9)


def test_white_noise_matches_the_density() -> None:
    s = preset_spline("hover", 60.0, seed=1)
    t = imu_stamps(s.t0_ns, s.t0_ns + int(60e9), 200.0)
    model = ImuErrorModel(
        gyro_noise_density=1e-3,
        gyro_random_walk=0.0,
        accel_noise_density=2e-2,
        accel_random_walk=0.0,
        initial_bg_sigma=0.0,
        initial_ba_sigma=0.0,
    )
    clean = synthesize_imu(s, t, ImuErrorModel.noise_free())
    noisy = synthesize_imu(s, t, model, seed=5)
    # discrete white noise sigma = density * sqrt(rate)
    np.testing.assert_allclose(np.std(noisy.gyro - clean.gyro, axis=0), 1e-3 * np.sqrt(200), rtol=0.03)
    np.testing.assert_allclose(np.std(noisy.accel - clean.accel, axis=0), 2e-2 * np.sqrt(200), rtol=0.03)
    np.testing.assert_array_equal(noisy.bg, 0.0)


def test_bias_random_walk_has_the_right_diffusion() -> None:
    s = preset_spline("hover", 60.0, seed=1)
    t = imu_stamps(s.t0_ns, s.t0_ns + int(60e9), 200.0)
    imu = synthesize_imu(s, t, ImuErrorModel(0.0, 1e-3, 0.0, 4e-3, 0.0, 0.0), seed=2)
    steps_g = np.diff(imu.bg, axis=0)
    steps_a = np.diff(imu.ba, axis=0)
    np.testing.assert_allclose(np.std(steps_g), 1e-3 * np.sqrt(0.005), rtol=0.03)
    np.testing.assert_allclose(np.std(steps_a), 4e-3 * np.sqrt(0.005), rtol=0.03)
    clean = synthesize_imu(s, t, ImuErrorModel.noise_free())
    np.testing.assert_allclose(imu.gyro - clean.gyro, imu.bg, atol=1e-12)  # bias is all that was added


def test_synthesis_is_seeded() -> None:
    s = preset_spline("slow", 3.0, seed=1)
    t = imu_stamps(s.t0_ns, s.t0_ns + int(3e9), 200.0)
    a = synthesize_imu(s, t, ImuErrorModel(), seed=1)
    b = synthesize_imu(s, t, ImuErrorModel(), seed=1)
    c = synthesize_imu(s, t, ImuErrorModel(), seed=2)
    np.testing.assert_array_equal(a.accel, b.accel)
    assert np.abs(a.accel - c.accel).max() > 1e-3
