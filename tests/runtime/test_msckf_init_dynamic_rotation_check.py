"""The dynamic initializer's rotation check (runtime.msckf.init_dynamic_rotation_check): the camera's keyframe
rotations against the gyro's. A right rig agrees; a gyroscope in deg/s or an inverted camera-IMU rotation is
refused before any solve, once per retry interval."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from runtime.errors import ConfigError
from runtime.events import ImuSample
from runtime.geometry import so3_exp, so3_log
from runtime.msckf.init_dynamic import DynamicInitializer
from runtime.msckf.init_dynamic_config import DynamicInitConfig
from runtime.msckf.init_dynamic_preintegration import preintegrate_keyframes
from runtime.msckf.init_dynamic_rotation_check import rotation_agreement
from tests.runtime.test_msckf_init_dynamic import CAM, R_IC, T_IC, Motion, feed
from tests.runtime.test_msckf_init_dynamic_window import biased_window


def _window(gyro_scale: float = 1.0):
    """A noise-free window (keyframes, preintegrations, IMU stamps, gyro) with its gyro scaled."""
    keyframes, (ti, gyro, accel), t_kf, _ = biased_window(np.zeros(3))
    gyro = gyro * gyro_scale
    imu = preintegrate_keyframes(ti, gyro, accel, t_kf, np.zeros(3), np.zeros(3), 1.7e-4, 2e-3)
    return keyframes, imu.between, ti, gyro


def test_a_right_rig_agrees_and_a_wrong_one_does_not():
    keyframes, between, ti, gyro = _window()
    right = rotation_agreement(keyframes, between, ti, gyro, R_IC, CAM.fx, 16, 0.2)
    assert right.measured == 5 and right.disagreeing == 0
    assert np.degrees(right.median_rad) < 0.05            # noise-free: the fits' own error
    # deg/s: 5-10 deg pairs turn 285-570 deg, wrapped; the gyro's path tells
    deg = rotation_agreement(*_window(np.degrees(1.0)), R_IC, CAM.fx, 16, 0.2)
    assert deg.measured == 5 and deg.gyro_scale == 5 and deg.axis == 0
    # an inverted rotation turns each pair as far about another axis: a difference of up to twice the
    # pair's rotation (5-10 deg here, so below the 0.2 rad bound in most pairs: caught on livelier motion)
    inverted = rotation_agreement(keyframes, between, ti, gyro, R_IC.T, CAM.fx, 16, 0.05)
    assert inverted.measured == 5 and inverted.axis == 5 and inverted.gyro_scale == 0, inverted
    assert inverted.median_rad > 50 * right.median_rad
    assert rotation_agreement(keyframes, between, ti, gyro, R_IC.T, CAM.fx, 16, 0.2).axis < 5


def test_the_scale_rule_and_its_bounds():
    """A gyro turning 18x as far (90-180 deg pairs, no wrap): the ratio decides, not the angle bound."""
    window = _window(18.0)
    assert rotation_agreement(*window, R_IC, CAM.fx, 16, np.pi).gyro_scale == 5
    assert rotation_agreement(*window, R_IC, CAM.fx, 16, np.pi, max_ratio=20.0).disagreeing == 0
    assert rotation_agreement(*window, R_IC, CAM.fx, 16, np.pi, min_gyro_rad=4.0).disagreeing == 0


def test_a_camera_fit_turning_farther_than_the_gyro_is_not_a_rig_mistake():
    """A two-view fit that takes translation for rotation turns farther than the gyro: neither mistake does
    that (a deg/s gyro turns farther, an axis mistake as far), so the pair is not counted."""
    keyframes, between, ti, gyro = _window()
    slow = [SimpleNamespace(dR=so3_exp(0.3 * so3_log(b.dR)), t0_ns=b.t0_ns, t1_ns=b.t1_ns) for b in between]
    agree = rotation_agreement(keyframes, slow, ti, gyro / 3.0, R_IC, CAM.fx, 16, 0.01)
    assert agree.measured == 5 and agree.disagreeing == 0 and agree.median_rad > 0.01


class _DegPerSecond:
    """Feeds an initializer the gyro in deg/s."""

    def __init__(self, init: DynamicInitializer) -> None:
        self.init = init

    def feed_imu(self, s: ImuSample) -> None:
        self.init.feed_imu(ImuSample(s.t_ns, np.degrees(np.asarray(s.gyro)), s.accel))

    def feed_tracks(self, *args) -> None:
        self.init.feed_tracks(*args)


def test_the_initializer_refuses_a_deg_per_second_gyro_before_solving_and_waits():
    init = DynamicInitializer(CAM, T_IC, DynamicInitConfig())
    feed(_DegPerSecond(init), Motion("general"), imu_hz=200.0)
    assert init.try_initialize() is None
    assert init.log.last.code == "rotation_mismatch", init.last_reason
    assert "in 5 of 5 keyframe pairs the gyro turns more than 15x" in init.last_reason
    assert "deg/s" in init.last_reason
    assert init.try_initialize() is None                  # the same window: waits, counted once
    assert init.report()["rejections"] == {"rotation_mismatch": 1}
    assert init.last_reason.startswith("rotation_mismatch")
    # the wait ends 0.5 s of camera time after the refused window's newest keyframe (3.45 s)
    feed(_DegPerSecond(init), Motion("general"), duration=0.3, imu_hz=200.0, t0=3.5)     # to 3.8 s
    assert init.try_initialize() is None and init.report()["rejections"] == {"rotation_mismatch": 1}
    feed(_DegPerSecond(init), Motion("general"), duration=0.3, imu_hz=200.0, t0=3.85)    # to 4.15 s
    assert init.try_initialize() is None and init.report()["rejections"] == {"rotation_mismatch": 2}
    # a reset forgets the wait with the data
    init.reset()
    feed(_DegPerSecond(init), Motion("general"), imu_hz=200.0, t0=5.0)
    assert init.try_initialize() is None and init.report()["rejections"] == {"rotation_mismatch": 3}
    assert init.report()["rotation_check"]["refused"] == 3


def test_the_check_runs_past_the_parallax_check_and_at_most_every_interval():
    """Turning in place (a right rig): refused for parallax before the check, which costs nothing there;
    a right rig with parallax is checked once per interval, never refused."""
    init = DynamicInitializer(CAM, T_IC, DynamicInitConfig())
    feed(init, Motion("rotation"), imu_hz=200.0)
    assert init.try_initialize() is None and init.log.last.code == "insufficient_parallax"
    assert init.report()["rotation_check"]["checks"] == 0
    init = DynamicInitializer(CAM, T_IC, DynamicInitConfig(mle_max_iterations=0))
    feed(init, Motion("general"), imu_hz=200.0)
    init.try_initialize()
    init.try_initialize()                                   # the same window: within the interval
    rc = init.report()["rotation_check"]
    assert rc["checks"] == 1 and rc["refused"] == 0 and rc["max_disagreeing_share"] == 0.0


def test_with_the_check_off_the_solves_refuse_the_deg_per_second_window_later():
    init = DynamicInitializer(CAM, T_IC, DynamicInitConfig(max_rotation_mismatch_fraction=1.0))
    feed(_DegPerSecond(init), Motion("general"), imu_hz=200.0)
    assert init.try_initialize() is None
    assert init.log.last.code not in ("rotation_mismatch", "few_frames", "short_window"), init.last_reason


@pytest.mark.parametrize("bad", [dict(max_rotation_mismatch_fraction=1.5),
                                 dict(max_rotation_mismatch_fraction=-0.1),
                                 dict(min_rotation_check_pairs=0), dict(rotation_mismatch_retry_s=-1.0),
                                 dict(rotation_check_max_ratio=1.0), dict(rotation_check_min_gyro_deg=-1.0),
                                 dict(rotation_mismatch_retry_s=float("inf")),
                                 dict(rotation_check_interval_s=-0.1), dict(max_visual_gyro_residual_rad=0.0),
                                 dict(max_visual_gyro_residual_rad=float("nan")),
                                 dict(num_pose=3, min_rotation_check_pairs=3)])
def test_the_check_settings_are_bounded(bad):
    with pytest.raises(ConfigError, match="dynamic_init"):
        DynamicInitConfig(**bad)
    # the keyframe pairs bound only with the check on: num_pose 3 works with the check off, as before it
    DynamicInitConfig(num_pose=3, max_rotation_mismatch_fraction=1.0)
