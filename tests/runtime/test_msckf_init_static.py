"""Static initializer: synthetic still-then-jerk IMU, rejections, disparity gating, real EuRoC IMU."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from runtime.errors import ConfigError
from runtime.events import ImuSample
from runtime.geometry import so3_exp
from runtime.msckf.init_common import ERROR_STATE_ORDER, gravity_angle_deg, rotation_from_up
from runtime.msckf.init_static import StaticInitConfig, StaticInitializer

G0 = 9.81
RATE = 200.0


def synth_imu(R_OI: np.ndarray, bg: np.ndarray, ba: np.ndarray, still_s: float, jerk_s: float,
              seed: int = 0, noise: float = 0.02) -> list[ImuSample]:
    """Still for still_s seconds, then random accelerations (std ~3 m/s^2) for jerk_s seconds."""
    rng = np.random.default_rng(seed)
    n_still, n_jerk = int(still_s * RATE), int(jerk_s * RATE)
    f_still = R_OI.T @ np.array([0.0, 0.0, G0])
    out = []
    for k in range(n_still + n_jerk):
        accel = f_still + ba + noise * rng.standard_normal(3)
        gyro = bg + 0.002 * rng.standard_normal(3)
        if k >= n_still:
            accel = accel + 3.0 * rng.standard_normal(3)
            gyro = gyro + 0.5 * rng.standard_normal(3)
        out.append(ImuSample(1_000_000_000 + int(round(k * 1e9 / RATE)), gyro, accel))
    return out


def run_until_init(init: StaticInitializer, samples: list[ImuSample]):
    for s in samples:
        init.feed_imu(s)
        res = init.try_initialize()
        if res is not None:
            return res, s
    return None, samples[-1]


R_TRUE = so3_exp(np.array([0.3, -0.2, 1.1]))
BG = np.array([0.01, -0.02, 0.005])


def test_jerk_initializes_from_the_still_half() -> None:
    ba = 0.2 * R_TRUE[2, :]  # a bias along gravity is what a static window can separate
    init = StaticInitializer(StaticInitConfig())
    res, at = run_until_init(init, synth_imu(R_TRUE, BG, ba, still_s=3.0, jerk_s=1.0))
    assert res is not None and res.source == "static"
    # it fires within the jerk, and the state time is the end of the (still) older half
    assert 3.0 < (at.t_ns - 1_000_000_000) * 1e-9 < 3.6
    assert res.t_ns == at.t_ns - 1_000_000_000 or abs(res.t_ns - (at.t_ns - 1_000_000_000)) <= 5_000_000
    assert gravity_angle_deg(res.gravity_in_imu, R_TRUE[2, :]) < 0.05
    np.testing.assert_allclose(res.R_OI @ res.R_OI.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(res.R_OI) == pytest.approx(1.0)
    np.testing.assert_allclose(res.bg, BG, atol=1e-3)
    np.testing.assert_allclose(res.ba, ba, atol=0.01)
    np.testing.assert_array_equal(res.p_OI, 0.0)
    np.testing.assert_array_equal(res.v_OI, 0.0)
    # at rest the accelerometer reads R_IO (0, 0, g0) + ba: the estimate explains the still mean exactly
    still = np.array([s.accel for s in synth_imu(R_TRUE, BG, ba, 3.0, 0.0)])[-200:]
    np.testing.assert_allclose(res.R_OI.T @ [0, 0, G0] + res.ba, still.mean(axis=0), atol=0.01)
    assert ERROR_STATE_ORDER == ("theta", "p", "v", "bg", "ba")
    np.testing.assert_allclose(np.sqrt(np.diag(res.cov)), np.repeat([0.02, 0.05, 0.01, 0.02, 0.02], 3))


def test_still_only_waits_for_jerk_then_still_mode_initializes() -> None:
    samples = synth_imu(R_TRUE, BG, np.zeros(3), still_s=4.0, jerk_s=0.0)
    jerk = StaticInitializer(StaticInitConfig(wait_for_jerk=True))
    res, _ = run_until_init(jerk, samples)
    assert res is None and jerk.log.last.code == "no_jerk"
    still = StaticInitializer(StaticInitConfig(wait_for_jerk=False))
    res, at = run_until_init(still, samples)
    assert res is not None
    assert abs((at.t_ns - 1_000_000_000) * 1e-9 - 2.0) < 0.011  # as soon as a full window exists
    assert gravity_angle_deg(res.gravity_in_imu, R_TRUE[2, :]) < 0.05


def test_moving_from_the_start_is_rejected() -> None:
    samples = synth_imu(R_TRUE, BG, np.zeros(3), still_s=0.0, jerk_s=3.0)
    for wait in (True, False):
        init = StaticInitializer(StaticInitConfig(wait_for_jerk=wait))
        res, _ = run_until_init(init, samples)
        assert res is None and init.log.last.code == "moving"
        assert "excitation" in init.last_reason and init.report()["rejections"]["moving"] > 0


@pytest.mark.parametrize("scale", [0.0, 0.1, 1 / G0, 3.0])
def test_an_accelerometer_that_does_not_read_gravity_at_rest_is_refused(scale: float) -> None:
    """Still samples whose specific force is zero (an IMU warming up), tiny, in g, or saturated are a counted
    rejection with the magnitude, not an error from the gravity direction."""
    still = synth_imu(R_TRUE, BG, np.zeros(3), 4.0, 0.0)
    samples = [ImuSample(s.t_ns, s.gyro, s.accel * scale) for s in still]
    init = StaticInitializer(StaticInitConfig(wait_for_jerk=False))
    res, _ = run_until_init(init, samples)
    assert res is None and init.log.last.code == "accel_magnitude"
    assert f"mean specific force {G0 * scale:.2f} m/s^2 at rest is not gravity's" in init.last_reason


def _feed_tracks(init: StaticInitializer, t0_ns: int, t1_ns: int, motion_start_ns: int | None) -> None:
    """30 tracks at 20 Hz, still until motion_start_ns, then moving 100 px/s."""
    rng = np.random.default_rng(1)
    base = rng.uniform(50, 400, size=(30, 2))
    for t in range(t0_ns, t1_ns, 50_000_000):
        shift = 0.0 if motion_start_ns is None or t < motion_start_ns else (t - motion_start_ns) * 1e-7
        init.feed_tracks(t, np.arange(30), base + shift)


def test_disparity_gates_the_decision() -> None:
    samples = synth_imu(R_TRUE, BG, np.zeros(3), still_s=3.0, jerk_s=1.0)
    t_end = samples[-1].t_ns
    # images keep still while the IMU jerks: no visual jerk
    init = StaticInitializer(StaticInitConfig())
    _feed_tracks(init, 1_000_000_000, t_end + 1, None)
    for s in samples:
        init.feed_imu(s)
    assert init.try_initialize() is None and init.log.last.code == "no_visual_jerk"
    # images move with the jerk: initializes
    init = StaticInitializer(StaticInitConfig())
    _feed_tracks(init, 1_000_000_000, t_end + 1, 4_000_000_000)
    for s in samples:
        init.feed_imu(s)
    assert init.try_initialize() is not None
    # too few tracks to judge
    init = StaticInitializer(StaticInitConfig(min_disparity_features=40))
    _feed_tracks(init, 1_000_000_000, t_end + 1, 4_000_000_000)
    for s in samples:
        init.feed_imu(s)
    assert init.try_initialize() is None and init.log.last.code == "few_features"


def test_bad_samples_are_dropped_and_counted() -> None:
    init = StaticInitializer()
    assert init.try_initialize() is None and init.log.last.code == "no_imu"
    init.feed_imu(ImuSample(10, np.zeros(3), np.array([0.0, 0.0, np.nan])))
    init.feed_imu(ImuSample(20, np.zeros(3), np.array([0.0, 0.0, G0])))
    init.feed_imu(ImuSample(20, np.zeros(3), np.array([0.0, 0.0, G0])))
    rep = init.report()
    assert rep["imu_dropped_nonfinite"] == 1 and rep["imu_dropped_out_of_order"] == 1
    assert init.try_initialize() is None and init.log.last.code == "no_imu"
    with pytest.raises(ConfigError):
        StaticInitConfig(init_imu_thresh=0.0)


def test_rotation_from_up_is_deterministic_and_aligned() -> None:
    rng = np.random.default_rng(3)
    for _ in range(20):
        up = rng.standard_normal(3)
        R = rotation_from_up(up * 5.0)
        np.testing.assert_allclose(R @ (up / np.linalg.norm(up)), [0, 0, 1], atol=1e-12)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(R, rotation_from_up(up), atol=1e-12)
    with pytest.raises(ValueError):
        rotation_from_up(np.zeros(3))


def _read_euroc_imu(path: Path) -> list[ImuSample]:
    t = np.loadtxt(path, delimiter=",", skiprows=1, usecols=0, dtype=np.int64)
    v = np.loadtxt(path, delimiter=",", skiprows=1)[:, 1:]
    return [ImuSample(int(t[k]), v[k, :3], v[k, 3:]) for k in range(t.size)]


def _gt_up(path: Path, t_ns: int) -> np.ndarray:
    """'Up' in the IMU frame from a EuRoC-format state file (quaternion w first) at the closest row."""
    t = np.loadtxt(path, delimiter=",", skiprows=1, usecols=0, dtype=np.int64)
    q = np.loadtxt(path, delimiter=",", skiprows=1)[:, 4:8]
    k = int(np.argmin(np.abs(t - t_ns)))
    assert abs(int(t[k]) - t_ns) < 20_000_000
    w, x, y, z = q[k] / np.linalg.norm(q[k])
    # third row of R_WI (body = IMU)
    return np.array([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)])


@pytest.mark.slow
@pytest.mark.parametrize("wait_for_jerk", [True, False])
def test_real_euroc_head_roll_pitch(euroc_head: Path, wait_for_jerk: bool) -> None:
    mav0 = Path(euroc_head) / "mav0"
    samples = _read_euroc_imu(mav0 / "imu0" / "data.csv")[: 200 * 10]
    init = StaticInitializer(StaticInitConfig(wait_for_jerk=wait_for_jerk))
    res, _ = run_until_init(init, samples)
    assert res is not None, init.last_reason
    # vicon2gt: the OpenVINS authors' recomputed ground truth (the original V1_01 orientation is off)
    up_true = _gt_up(mav0 / "state_groundtruth_estimate0" / "full_sequence_vicon2gt.csv", res.t_ns)
    assert gravity_angle_deg(res.gravity_in_imu, up_true) < 1.0
