"""Keyframe/feature selection, excitation measures, keyframe preintegration and the visual gyro bias."""

from __future__ import annotations

import numpy as np
import pytest

from runtime.events import ImuSample
from runtime.geometry import so3_exp, so3_log
from runtime.msckf.init_dynamic import DynamicInitializer
from runtime.msckf.init_dynamic_excitation import gyro_rotation_deg, median_parallax_deg
from runtime.msckf.init_dynamic_gyro_bias import visual_gyro_bias
from runtime.msckf.init_dynamic_preintegration import preintegrate_keyframes
from runtime.msckf.init_dynamic_window import frames_in_window, keep_features, pick_keyframes, select_features
from tests.runtime.test_msckf_init_dynamic import CAM, R_IC, T_IC, Motion, landmarks


def frame(t_ns: int, ids: list[int], xy: list[tuple[float, float]] | None = None) -> tuple:
    xy_arr = np.array(xy if xy is not None else [(0.01 * i, -0.02 * i) for i in ids], dtype=float)
    return (t_ns, np.array(ids, dtype=np.int64), 100.0 * xy_arr, xy_arr.reshape(-1, 2))


def test_frames_in_window_waits_for_the_imu_and_keeps_the_window() -> None:
    frames = [frame(t, [1]) for t in range(0, 1000, 100)]  # 0, 100, ..., 900 ns
    got = frames_in_window(frames, t_imu_newest_ns=620, time_offset_ns=20, window_ns=300)
    assert [f[0] for f in got] == [300, 400, 500, 600]  # 600 + 20 <= 620 is covered, 700 is not
    assert [f[0] for f in frames_in_window(frames, None, 0, 250)] == [700, 800, 900]
    # no frame reached by the IMU yet: the oldest one alone
    assert [f[0] for f in frames_in_window(frames, -5, 0, 300)] == [0]


def test_pick_keyframes_spreads_by_index() -> None:
    frames = [frame(t, [1]) for t in range(11)]
    assert [f[0] for f in pick_keyframes(frames, 6)] == [0, 2, 4, 6, 8, 10]
    assert [f[0] for f in pick_keyframes(frames[:3], 6)] == [0, 1, 2]  # never repeats a frame


def test_select_features_counts_orders_and_drops_nonfinite() -> None:
    kfs = [
        frame(0, [5, 7, 9, 2]),
        frame(1, [7, 9, 2], [(0.1, 0.2), (np.nan, 0.0), (0.3, 0.4)]),
        frame(2, [7, 2, 5]),
        frame(3, [7, 9]),
    ]
    ids, obs = select_features(kfs, min_observations=3, max_features=2)
    # counts: 7 -> 4, 2 -> 3, 9 -> 3, 5 -> 2; ties by smaller id, at most 2
    np.testing.assert_array_equal(ids, [7, 2])
    expected = [
        (0, 0, 0.07, -0.14), (0, 1, 0.02, -0.04),
        (1, 0, 0.1, 0.2), (1, 1, 0.3, 0.4),
        (2, 0, 0.07, -0.14), (2, 1, 0.02, -0.04),
        (3, 0, 0.07, -0.14),
    ]  # fmt: skip
    np.testing.assert_allclose(obs, expected)
    ids, obs = select_features(kfs, min_observations=3, max_features=10)
    np.testing.assert_array_equal(ids, [7, 2, 9])
    assert not np.any((obs[:, 0] == 1) & (obs[:, 1] == 2))  # the NaN observation of id 9 is dropped
    kept = keep_features(obs, np.array([True, False, True]))
    np.testing.assert_array_equal(np.unique(kept[:, 1]), [0, 1])
    np.testing.assert_allclose(kept[kept[:, 1] == 1, 2:], obs[obs[:, 1] == 2, 2:])


def test_gyro_rotation_of_a_constant_rate() -> None:
    t = np.arange(0, 2_000_000_001, 5_000_000, dtype=np.int64)  # 2 s at 200 Hz
    w = np.array([0.3, -0.4, 0.1])
    bg = np.array([0.05, 0.05, 0.05])
    gyro = np.tile(w + bg, (t.size, 1))
    # only the samples inside [0.5 s, 1.5 s]: |w| * 1 s
    deg = gyro_rotation_deg(t, gyro, 500_000_000, 1_500_000_000, bg)
    assert deg == pytest.approx(np.degrees(np.linalg.norm(w)), rel=1e-12)
    assert gyro_rotation_deg(t, gyro, 10, 20, bg) == 0.0


def test_median_parallax_is_zero_for_rotation_and_matches_the_geometry_for_translation() -> None:
    rng = np.random.default_rng(0)
    p_C = np.c_[rng.uniform(-1, 1, (9, 2)), rng.uniform(3, 5, 9)]
    R_01 = so3_exp(np.array([0.1, -0.2, 0.3]))
    R_CI = R_IC.T
    xy0 = p_C[:, :2] / p_C[:, 2:]
    p_C1 = p_C @ (R_CI @ R_01.T @ R_IC).T  # same camera centre, rotated
    xy1 = p_C1[:, :2] / p_C1[:, 2:]
    obs = np.array([(k, n, *xy[n]) for k, xy in enumerate((xy0, xy1)) for n in range(9)])
    assert median_parallax_deg(obs, np.stack([np.eye(3), R_01]), R_IC) < 1e-6
    # no rotation, camera moved by b along its x axis: angle between the two rays to each point
    b = np.array([0.4, 0.0, 0.0])
    p_C1 = p_C - b
    xy1 = p_C1[:, :2] / p_C1[:, 2:]
    obs = np.array([(k, n, *xy[n]) for k, xy in enumerate((xy0, xy1)) for n in range(9)])
    cos = np.einsum("ni,ni->n", p_C, p_C1) / np.linalg.norm(p_C, axis=1) / np.linalg.norm(p_C1, axis=1)
    expected = np.median(np.degrees(np.arccos(cos)))
    got = median_parallax_deg(obs, np.stack([np.eye(3), np.eye(3)]), R_IC)
    assert got == pytest.approx(expected, rel=1e-9)


def biased_window(bg: np.ndarray, imu_hz: float = 1000.0) -> tuple:
    """Noise-free window of Motion('general') with a constant gyro bias: keyframes, IMU arrays, t_kf."""
    init = DynamicInitializer(CAM, T_IC)
    motion = Motion("general")
    L = landmarks()
    for i in range(int(2.5 * imu_hz) + 1):
        t = 1.0 + i / imu_hz
        _, _, _, w, f = motion.state(t)
        init.feed_imu(ImuSample(int(round(t * 1e9)), w + bg, f))
    for j in range(50):
        t = 1.0 + j / 20
        R, p, _, _, _ = motion.state(t)
        p_C = (L - (p + R @ T_IC[:3, 3])) @ (R @ R_IC)
        uv = CAM.project(p_C)
        ok = (p_C[:, 2] > 0.5) & (uv[:, 0] > 0) & (uv[:, 0] < 639) & (uv[:, 1] > 0) & (uv[:, 1] < 479)
        init.feed_tracks(int(round(t * 1e9)), np.flatnonzero(ok), uv[ok])
    frames = frames_in_window(list(init.tracks.frames), init.imu.newest_ns(), 0, 2_000_000_000)
    keyframes = pick_keyframes(frames, 6)
    t_kf = np.array([k[0] for k in keyframes], dtype=np.int64)
    return keyframes, init.imu.arrays(), t_kf, motion


def test_keyframe_preintegration_matches_the_true_motion() -> None:
    keyframes, (ti, gyro, accel), t_kf, motion = biased_window(np.zeros(3))
    imu = preintegrate_keyframes(ti, gyro, accel, t_kf, np.zeros(3), np.zeros(3), 1.7e-4, 2e-3)
    R0, p0, v0, _, _ = motion.state(t_kf[0] * 1e-9)
    g = np.array([0.0, 0.0, -9.81])
    assert len(imu.between) == 5 and imu.dt_0k[0] == 0.0
    for k, t in enumerate(t_kf * 1e-9):
        R, p, v, _, _ = motion.state(t)
        dt = t - t_kf[0] * 1e-9
        assert imu.dt_0k[k] == pytest.approx(dt, abs=1e-12)
        assert np.linalg.norm(so3_log(imu.R_0k[k].T @ R0.T @ R)) < 1e-6  # 1 kHz discretisation
        np.testing.assert_allclose(imu.dv_0k[k], R0.T @ (v - v0 - g * dt), atol=1e-5)
        np.testing.assert_allclose(imu.dp_0k[k], R0.T @ (p - p0 - v0 * dt - 0.5 * g * dt * dt), atol=1e-5)
    for k, pre in enumerate(imu.between):  # neighbours compose to the from-first terms
        assert np.linalg.norm(so3_log(imu.R_0k[k + 1].T @ imu.R_0k[k] @ pre.dR)) < 1e-12
        assert pre.cov.shape == (9, 9)


def test_visual_gyro_bias_recovers_a_constant_bias() -> None:
    bg = np.array([0.01, -0.008, 0.012])
    keyframes, (ti, gyro, accel), t_kf, _ = biased_window(bg)
    imu = preintegrate_keyframes(ti, gyro, accel, t_kf, np.zeros(3), np.zeros(3), 1.7e-4, 2e-3)
    cv2 = pytest.importorskip("cv2")
    cv2.setRNGSeed(0)
    est = visual_gyro_bias(keyframes, imu.between, np.zeros(3), R_IC, CAM.fx, 16, 0.2)
    assert est is not None
    np.testing.assert_allclose(est, bg, atol=1e-5)  # bias is ~1e-2 rad/s
    # a gate no pair passes leaves no estimate
    assert visual_gyro_bias(keyframes, imu.between, np.zeros(3), R_IC, CAM.fx, 16, 1e-9) is None
