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


def test_gauss_markov_process_has_its_std_and_correlation_time() -> None:
    from drivers.sim.imu_synth import gauss_markov

    dt = np.full(400_000, 0.005)
    m = gauss_markov(dt, 0.04, 0.5, np.random.default_rng(3))
    np.testing.assert_allclose(np.std(m, axis=0), 0.04, rtol=0.05)
    lag = 100  # 0.5 s = tau: autocorrelation exp(-1)
    r = [np.corrcoef(m[:-lag, i], m[lag:, i])[0, 1] for i in range(3)]
    np.testing.assert_allclose(r, np.exp(-1.0), atol=0.03)
    r1 = [np.corrcoef(m[:-1, i], m[1:, i])[0, 1] for i in range(3)]
    np.testing.assert_allclose(r1, np.exp(-0.005 / 0.5), atol=2e-3)


def test_gauss_markov_errors_are_part_of_the_true_bias_and_leave_other_draws_alone() -> None:
    s = preset_spline("slow", 6.0, seed=1)
    t = imu_stamps(s.t0_ns, s.t0_ns + int(6e9), 200.0)
    plain = synthesize_imu(s, t, ImuErrorModel(), seed=4)
    gm = synthesize_imu(s, t, ImuErrorModel(gyro_gm_sigma=1e-3, gyro_gm_tau_s=2.0, accel_gm_sigma=0.04,
                                            accel_gm_tau_s=0.5), seed=4)
    # the same white noise and random walk; the difference is exactly the added process, in bg / ba
    np.testing.assert_allclose(gm.gyro - gm.bg, plain.gyro - plain.bg, atol=1e-12)
    np.testing.assert_allclose(gm.accel - gm.ba, plain.accel - plain.ba, atol=1e-12)
    extra = gm.ba - plain.ba
    assert 0.02 < np.std(extra) < 0.06


def test_imu_error_models_refuse_bad_values_and_unknown_profiles() -> None:
    from drivers.sim import SimConfig
    from drivers.sim.imu_synth import imu_errors_for
    from runtime.errors import ConfigError

    with pytest.raises(ConfigError, match="accel_gm_sigma"):
        ImuErrorModel(accel_gm_sigma=-0.1)
    with pytest.raises(ConfigError, match="gyro_gm_tau_s"):
        ImuErrorModel(gyro_gm_tau_s=0.0)
    with pytest.raises(ConfigError, match="gyro_noise_density"):
        ImuErrorModel(gyro_noise_density=float("nan"))
    with pytest.raises(ConfigError, match="unknown synthetic IMU profile"):
        imu_errors_for("consumer")
    with pytest.raises(ConfigError, match="imu_profile"):
        SimConfig(imu_profile="consumer")
    assert imu_errors_for("datasheet") == ImuErrorModel()
    assert imu_errors_for("euroc-measured").accel_gm_sigma > 0


@pytest.mark.parametrize("profile, low, high", [("datasheet", 0.0, 0.5), ("euroc-measured", 0.8, 1.25)])
def test_the_measured_profile_drifts_as_the_real_euroc_imu(profile: str, low: float, high: float) -> None:
    """Along V1_02's true trajectory, 1 s of dead reckoning from the true state (constant biases fitted
    over the sequence, `davio bench imu-drift`'s protocol): the real IMU against the truth EuRoC-trajectory
    recordings render from is the independent expectation; the datasheet densities alone drift far less."""
    from conftest import shared_path

    from drivers.euroc import read_euroc_imu_csv
    from drivers.sim.imu_consistent import DEFAULT_SMOOTHING_S, imu_consistent_groundtruth
    from drivers.trajectory_files import read_trajectory
    from tools.benchmarks.real_imu_drift import drift_curve, synthetic_curve

    folder = shared_path("euroc_imu_gt", "V1_02_medium")
    gt = read_trajectory(folder / "groundtruth.csv", strictly_increasing=True)
    t_real, gyro, accel = read_euroc_imu_csv(folder / "imu0.csv", policy="strict")
    inside = (t_real >= gt.t_ns[0]) & (t_real <= gt.t_ns[-1])
    # the truth EuRoC-trajectory recordings render from: what the filter faces there
    rendered = imu_consistent_groundtruth(gt, t_real[inside], gyro[inside], DEFAULT_SMOOTHING_S)
    real = drift_curve(t_real, gyro, accel, rendered, [1.0], 1.0)["1"]
    sim = synthetic_curve(gt, profile, [1.0], 1.0)["1"]
    ratio = sim["position_m"]["median"] / real["position_m"]["median"]
    assert low < ratio < high, ratio
