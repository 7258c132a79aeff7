"""The camera-IMU time-offset check of the feed-forward start-up (runtime/ffinit/time_offset_check.py): a
known shift recovered on synthetic windows (the camera's rotations integrated in closed form at the true
offset), the cases it must leave alone, and a simulated window solved at the offset it finds."""
from __future__ import annotations

import numpy as np
import pytest

from runtime.ffinit.config import FFInitConfig
from runtime.ffinit.time_offset_check import OffsetScan, fit_time_offset, scan_time_offset
from runtime.ffinit.window import ImageObservations
from runtime.geometry import so3_exp

T0 = 1_000_000_000
R_IC = so3_exp(np.array([0.3, -1.2, 0.4]))


def _omega(t_s: np.ndarray, constant: bool) -> np.ndarray:
    """(n, 3) angular rate, rad/s, IMU frame: a changing rate, or a constant one."""
    if constant:
        return np.tile([0.2, -0.5, 0.3], (len(t_s), 1))
    return np.column_stack([0.8 * np.sin(2.0 * t_s), 0.6 * np.cos(3.1 * t_s), 0.4 * np.sin(1.3 * t_s + 0.5)])


def _window(true_offset_s: float, constant: bool = False, bias=(0.0, 0.0, 0.0)):
    """Five images 0.2 s apart whose DA3 rotations are the body's true ones at t_cam + true_offset_s; the
    gyro (1 kHz, plus a constant bias) reads the rate of `_omega`."""
    imu_t = np.arange(T0 - 10**9, T0 + 3 * 10**9, 1_000_000, dtype=np.int64)
    t_s = (imu_t - T0) * 1e-9
    w = _omega(t_s, constant)
    R = [np.eye(3)]                       # the body's orientation sample by sample (fine steps: closed form)
    for k in range(len(imu_t) - 1):
        R.append(R[-1] @ so3_exp(0.5 * (w[k] + w[k + 1]) * (t_s[k + 1] - t_s[k])))
    R = np.array(R)
    t_cam = [T0 + int(i * 0.2e9) for i in range(5)]
    at = [R[np.searchsorted(imu_t, t + int(round(true_offset_s * 1e9)))] for t in t_cam]
    obs = [ImageObservations(np.zeros((0, 2)), np.zeros(0), np.zeros(0),
                             R_IC.T @ at[0].T @ at[i] @ R_IC, np.zeros(3)) for i in range(5)]
    return t_cam, obs, imu_t, w + np.asarray(bias)


@pytest.mark.parametrize("rig_error_s", [0.04, -0.07, 0.12])
def test_a_wrong_offset_is_found_to_the_millisecond(rig_error_s):
    t_cam, obs, imu_t, gyro = _window(0.0, bias=(0.01, -0.02, 0.015))
    fit = fit_time_offset(t_cam, obs, R_IC, imu_t, gyro, rig_error_s, FFInitConfig())
    assert fit is not None
    assert fit.shift_s == pytest.approx(-rig_error_s, abs=1e-3)     # between the 5 ms grid points
    assert fit.rms_deg < 0.02 and fit.in_use_rms_deg > 10 * fit.rms_deg
    early_or_late = "late" if rig_error_s > 0 else "early"
    assert f"{abs(fit.shift_s) * 1e3:.0f} ms {early_or_late} against the IMU" in fit.describe(rig_error_s)


def test_the_scan_is_flat_at_the_truth_and_grows_away_from_it():
    t_cam, obs, imu_t, gyro = _window(0.03)
    scan = scan_time_offset(t_cam, obs, R_IC, imu_t, gyro, 0.0, np.arange(-8, 9) * 0.01)
    assert isinstance(scan, OffsetScan)
    assert scan.shifts_s[scan.best] == pytest.approx(0.03)
    assert scan.rms_deg[scan.best] < 0.01
    # the residual grows monotonically with the distance from the truth on either side
    left, right = scan.rms_deg[:scan.best + 1], scan.rms_deg[scan.best:]
    assert np.all(np.diff(left) < 0) and np.all(np.diff(right) > 0)


def test_the_right_offset_is_left_alone():
    t_cam, obs, imu_t, gyro = _window(0.02)
    assert fit_time_offset(t_cam, obs, R_IC, imu_t, gyro, 0.02, FFInitConfig()) is None
    # within time_offset_check_s of the rig's: not worth a word
    assert fit_time_offset(t_cam, obs, R_IC, imu_t, gyro, 0.03, FFInitConfig()) is None
    assert fit_time_offset(t_cam, obs, R_IC, imu_t, gyro, 0.03, FFInitConfig(time_offset_check_s=0.005))


def test_a_constant_rate_does_not_determine_the_offset():
    """Turning at a constant rate, every shift fits alike: no finding (and the rig's offset does no harm to
    the window's rotations)."""
    t_cam, obs, imu_t, gyro = _window(0.0, constant=True)
    assert fit_time_offset(t_cam, obs, R_IC, imu_t, gyro, 0.08, FFInitConfig()) is None


def test_beyond_the_scanned_range_nothing_is_claimed():
    t_cam, obs, imu_t, gyro = _window(0.0)
    assert fit_time_offset(t_cam, obs, R_IC, imu_t, gyro, 0.3, FFInitConfig()) is None        # the edge
    assert fit_time_offset(t_cam, obs, R_IC, imu_t, gyro, 0.3, FFInitConfig(time_offset_check_range_s=0.4))


def test_live_the_pairs_the_imu_does_not_cover_are_left_out():
    """Live, the IMU ends near the newest image: a shift towards later IMU times is scanned on the pairs the
    samples cover (the last one left out), and with fewer than three such pairs nothing is claimed."""
    t_cam, obs, imu_t, gyro = _window(0.0)
    keep = imu_t < t_cam[-1] + 50_000_000                # 50 ms past the window, less than the 200 ms scanned
    fit = fit_time_offset(t_cam, obs, R_IC, imu_t[keep], gyro[keep], -0.05, FFInitConfig())
    assert fit is not None and fit.shift_s == pytest.approx(0.05, abs=1e-3)
    short = imu_t < t_cam[-2]                            # only the first pair is covered at every shift
    grid = np.array([-0.2, 0.0, 0.2])
    assert scan_time_offset(t_cam, obs, R_IC, imu_t[short], gyro[short], 0.0, grid) is None
    assert fit_time_offset(t_cam, obs, R_IC, imu_t[short], gyro[short], -0.05, FFInitConfig()) is None


def test_an_imu_sample_exactly_at_the_scans_end_is_not_a_gap():
    """Frame stamps whose shifted ends fall exactly on IMU samples (simulated stamps do): float rounding of
    the query times must not stop the scan (a review found a ValueError from the interpolation)."""
    t_cam, obs, imu_t, gyro = _window(0.0)
    stamps = [T0 + int(s * 1e9) for s in (0.0, 0.2, 0.35, 0.5, 0.7)]
    obs_at = [obs[0], obs[1], obs[2], obs[3], obs[4]]
    keep = imu_t <= stamps[-1] + 200_000_000                # the last sample exactly at the last shifted end
    scan = scan_time_offset(stamps, obs_at, R_IC, imu_t[keep], gyro[keep], 0.0, np.arange(-40, 41) * 0.005)
    assert scan is not None and np.isfinite(scan.rms_deg).all()


def test_config_refuses_a_step_not_below_the_range():
    from runtime.errors import ConfigError

    with pytest.raises(ConfigError, match="time_offset_check_step_s"):
        FFInitConfig(time_offset_check_step_s=0.2, time_offset_check_range_s=0.2)


@pytest.mark.parametrize("name", ["time_offset_check_s", "time_offset_check_ratio",
                                  "time_offset_check_range_s", "time_offset_check_step_s"])
def test_config_refuses_non_positive_values(name):
    from runtime.errors import ConfigError

    with pytest.raises(ConfigError, match=name):
        FFInitConfig(**{name: 0.0})


@pytest.fixture(scope="module")
def handheld_window():
    from drivers.sim import SimConfig, SimRecording
    from runtime.events import Frame
    from tools.benchmarks.ffinit_accuracy import window_frame_indices

    rec = SimRecording.from_preset(SimConfig(preset="handheld", seconds=4, seed=0))
    cam = rec.rig.camera
    idx = window_frame_indices(rec.frame_stamps_ns, int(rec.frame_stamps_ns[0]) + 10**9)
    frames = [Frame(int(rec.frame_stamps_ns[i]), np.zeros((cam.height, cam.width), np.uint8)) for i in idx]
    return rec, frames


def _solve(rec, frames, rig_error_s: float, cfg: FFInitConfig | None = None):
    from models.emulated_da3 import EmulatedDA3
    from runtime.ffinit.initializer import FeedForwardInitializer

    cam, imu, T_IC = rec.rig.camera, rec.imu, np.asarray(rec.rig.T_IC)
    model = EmulatedDA3(rec.gt_source, cam.K, cam.width, cam.height, preset="base", seed=0)
    offset = (rec.rig.time_offset_s or 0.0) + rig_error_s
    init = FeedForwardInitializer(model, T_IC[:3, :3], T_IC[:3, 3], offset, cfg)
    return init.solve(frames, imu.t_ns, imu.gyro, imu.accel), model


def test_a_simulated_window_is_solved_at_the_offset_its_rotations_fit(handheld_window):
    """The hand-held preset with the emulated DA3, its rig's offset 60 ms wrong: refused as
    rotation_inconsistent without the check; with it, solved at the true offset (within 2 ms) to the
    scale and velocity the right rig gives; and named, not solved, when correction is off."""
    from runtime.msckf.init_common import InitResult

    rec, frames = handheld_window
    right, model = _solve(rec, frames, 0.0)
    assert isinstance(right, InitResult) and "time_offset_s" not in right.info
    named, _ = _solve(rec, frames, 0.06, FFInitConfig(correct_time_offset=False))
    assert named.reason == "time_offset" and "ms late" in named.detail
    corrected, _ = _solve(rec, frames, 0.06)
    assert isinstance(corrected, InitResult)
    assert corrected.info["time_offset_s"] == pytest.approx(rec.rig.time_offset_s or 0.0, abs=0.002)
    assert corrected.info["time_offset_shift_s"] == pytest.approx(-0.06, abs=0.002)
    assert corrected.info["scale"] == pytest.approx(right.info["scale"], rel=0.02)
    assert np.linalg.norm(corrected.v_OI - right.v_OI) < 0.02
    # what the check replaces: a plain refusal
    off = FFInitConfig(time_offset_check_range_s=0.02)            # the scan cannot reach 60 ms
    assert _solve(rec, frames, 0.06, off)[0].reason == "rotation_inconsistent"


def test_a_refusal_a_longer_span_may_cure_keeps_its_reason_and_seed_at_the_found_offset(handheld_window):
    """Solved at the offset found, a window refused for too short a span keeps that reason and its re-solve
    seed (the start-up re-solves it, at the adopted offset), and carries the finding."""
    rec, frames = handheld_window
    strict = FFInitConfig(max_scale_uncertainty=1e-6)              # every scale is too uncertain
    res, _ = _solve(rec, frames, 0.06, strict)
    assert res.reason == "scale_unobservable" and res.seed is not None
    assert res.time_offset_s == pytest.approx(rec.rig.time_offset_s or 0.0, abs=0.002)
    assert "at the offset the rotations fit" in res.detail
