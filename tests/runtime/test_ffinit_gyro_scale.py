"""The gyroscope-scale check of the feed-forward start-up (runtime/ffinit/gyro_scale.py): closed-form rates
on synthetic windows, and a simulated window whose gyroscope is logged in deg/s."""
from __future__ import annotations

import numpy as np
import pytest

from runtime.ffinit.config import FFInitConfig
from runtime.ffinit.gyro_scale import check_gyro_scale, rotation_rates
from runtime.ffinit.window import ImageObservations
from runtime.geometry import so3_exp

T0 = 1_000_000_000


def _window(rate: float, axis=(0.3, -0.2, 0.93), n: int = 5, spacing_s: float = 0.2):
    """Images turning at `rate` rad/s about a fixed axis; the gyro at 200 Hz reading that rate."""
    a = np.asarray(axis) / np.linalg.norm(axis)
    t_cam = [T0 + int(i * spacing_s * 1e9) for i in range(n)]
    obs = [ImageObservations(np.zeros((0, 2)), np.zeros(0), np.zeros(0), so3_exp(a * rate * i * spacing_s),
                             np.zeros(3)) for i in range(n)]
    imu_t = np.arange(T0 - 10**9, t_cam[-1] + 10**9, 5_000_000, dtype=np.int64)
    gyro = np.tile(a * rate, (len(imu_t), 1))
    return t_cam, obs, imu_t, gyro


def test_rates_are_the_closed_form_ones():
    t_cam, obs, imu_t, gyro = _window(0.5)
    g, d = rotation_rates(t_cam, obs, imu_t, gyro)
    assert g == pytest.approx(0.5, rel=1e-9) and d == pytest.approx(0.5, rel=1e-9)
    # the chord is at most the path: a gyro that also turns about another axis between images
    wobble = gyro + np.column_stack([np.sin(np.arange(len(imu_t)) * 0.9), np.zeros((len(imu_t), 2))])
    assert rotation_rates(t_cam, obs, imu_t, wobble)[0] > 0.5
    # samples are taken on the IMU clock: t_cam + time offset; none inside the span gives NaN
    assert np.isnan(rotation_rates(t_cam, obs, imu_t, gyro, time_offset_s=100.0)[0])


@pytest.mark.parametrize("factor, refused, hint", [
    (1.0, False, None),
    (14.0, False, None),                            # below the 15x bound
    (np.degrees(1.0), True, "deg/s"),               # a gyroscope logging deg/s
    (250.0, True, "wrong gyroscope scale"),         # another wrong scale: no deg/s hint
])
def test_a_gyro_turning_far_faster_than_the_camera_is_refused(factor, refused, hint):
    t_cam, obs, imu_t, gyro = _window(0.5)
    rej = check_gyro_scale(t_cam, obs, imu_t, gyro * factor, 0.0, FFInitConfig())
    assert (rej is not None) == refused
    if refused:
        assert rej.reason == "gyro_scale" and hint in rej.detail and f"{factor:.1f}x" in rej.detail


def test_no_judgement_while_the_camera_barely_turns():
    t_cam, obs, imu_t, gyro = _window(0.05)                     # below gyro_scale_min_rate (0.1 rad/s)
    assert check_gyro_scale(t_cam, obs, imu_t, gyro * 57.3, 0.0, FFInitConfig()) is None
    assert check_gyro_scale(t_cam, obs, imu_t, gyro * 57.3, 0.0, FFInitConfig(gyro_scale_min_rate=0.04))


def test_config_refuses_a_non_positive_bound():
    from runtime.errors import ConfigError

    with pytest.raises(ConfigError, match="max_gyro_rate_ratio"):
        FFInitConfig(max_gyro_rate_ratio=0.0)


@pytest.mark.slow
def test_a_simulated_window_with_a_gyro_in_deg_s_is_refused_for_that_reason():
    """The hand-held preset with the emulated DA3: the right units pass this check (the window is judged on
    its own merits), the same samples in deg/s are refused as gyro_scale, not for a bias step."""
    from drivers.sim import SimConfig, SimRecording
    from models.emulated_da3 import EmulatedDA3
    from runtime.events import Frame
    from runtime.ffinit.initializer import FeedForwardInitializer
    from tools.benchmarks.ffinit_accuracy import window_frame_indices

    rec = SimRecording.from_preset(SimConfig(preset="handheld", seconds=4, seed=0))
    cam, imu, T_IC = rec.rig.camera, rec.imu, np.asarray(rec.rig.T_IC)
    idx = window_frame_indices(rec.frame_stamps_ns, int(rec.frame_stamps_ns[0]) + 10**9)
    frames = [Frame(int(rec.frame_stamps_ns[i]), np.zeros((cam.height, cam.width), np.uint8)) for i in idx]
    reasons = []
    for gyro in (imu.gyro, np.degrees(imu.gyro)):
        model = EmulatedDA3(rec.gt_source, cam.K, cam.width, cam.height, preset="base", seed=0)
        init = FeedForwardInitializer(model, T_IC[:3, :3], T_IC[:3, 3], rec.rig.time_offset_s or 0.0)
        res = init.solve(frames, imu.t_ns, gyro, imu.accel)
        reasons.append(getattr(res, "reason", "accepted"))
    assert reasons[0] != "gyro_scale" and reasons[1] == "gyro_scale"
