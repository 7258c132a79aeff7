"""Calibration-withheld bring-up through the pipeline: with T_IC withheld, hand-eye on emulated-DA3
windows estimates R_IC (checked against the simulator's true extrinsics), then tracking starts with
online calibration and publishes."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from drivers.sim import SimConfig, SimRecording
from models.emulated_da3 import EmulatedDA3
from runtime.bringup import BringUpConfig, HandEyeBringUp, _two_view_rotations
from runtime.config import DavioConfig
from runtime.errors import ConfigError
from runtime.ffinit.window import Rejection
from runtime.pipeline import VioPipeline
from runtime.scheduler import FastClock, Scheduler


def test_without_a_model_the_bringup_takes_its_rotations_from_the_tracked_features():
    """No depth model: two-view fits of the KLT tracks replace DA3's rotations; R_IC against the simulator's
    (measured 0.26 deg on this recording; 0.06 deg with the emulated DA3-Base)."""
    rec = SimRecording.from_preset(SimConfig(preset="aggressive", seconds=12.0, seed=4, camera_rate_hz=10.0))
    withheld = rec.rig.replace(T_IC=None, time_offset_s=None)
    cfg = DavioConfig()
    pipe = VioPipeline(withheld, None, replace(cfg, mapping=replace(cfg.mapping, enabled=False)))
    Scheduler(FastClock(0.5)).run(rec.events(), pipe)
    rep = pipe.report()["bringup"]
    assert rep["rotation_source"] == "tracks" and rep["R_IC"] is not None, rep
    n_rot = sum(rep["two_view_models"].values())    # every window received, 4 rotations each
    assert n_rot % 4 == 0 and n_rot >= 4 * rep["windows_used"]
    err = np.degrees(Rotation.from_matrix(np.array(rep["R_IC"]).T @ rec.rig.T_IC[:3, :3]).magnitude())
    assert err < 1.5, err
    assert len(pipe.published) > 5


def test_a_bringup_without_a_model_needs_the_focal_length_and_sane_settings():
    with pytest.raises(ValueError, match="focal length"):
        HandEyeBringUp(None)
    with pytest.raises(ConfigError, match="bringup.two_view_min_tracks"):
        BringUpConfig(two_view_min_tracks=10)


def test_images_whose_features_left_the_view_are_chained_frame_to_frame():
    """A turn about two axes (40 and 50 deg/s: steps that do not commute) for 0.8 s at 20 Hz, each feature
    tracked for 0.35 s (its id then changes): the
    window's later images share no feature with its first one and are placed by chaining; one frame without
    features (dark) is not held. Against the true rotations of a pure rotation (points 5 m away)."""
    rng = np.random.default_rng(4)
    d = rng.normal(size=(3000, 3))
    X = 5.0 * d / np.linalg.norm(d, axis=1, keepdims=True)
    bu = HandEyeBringUp(None, BringUpConfig(), focal_px=458.0)
    truth = {}
    for k in range(17):
        t_ns = 10**9 + k * 50_000_000
        s_k = k * 0.05
        R_C0Ck = (Rotation.from_rotvec([np.radians(40.0) * s_k, 0, 0])
                  * Rotation.from_rotvec([0, np.radians(50.0) * s_k, 0])).as_matrix()
        truth[t_ns] = R_C0Ck
        Xc = X @ R_C0Ck          # points in camera k: R_CkC0 X = R_C0Ck^T X
        vis = np.flatnonzero((Xc[:, 2] > 0.5) & (np.abs(Xc[:, 0]) < 0.8 * Xc[:, 2])
                             & (np.abs(Xc[:, 1]) < 0.6 * Xc[:, 2]))
        xy = Xc[vis, :2] / Xc[vis, 2:] + rng.normal(0, 0.3 / 458.0, (len(vis), 2))
        ids = vis * 100 + (k + vis) // 7        # a feature's id lasts 7 frames
        bu.on_tracks(t_ns, ids if k != 9 else ids[:0], xy if k != 9 else xy[:0])
    assert len(bu.tracks) == 16
    span = list(bu.tracks)
    stamps = [10**9 + i * 200_000_000 for i in range(5)]
    R, how = _two_view_rotations(span, stamps, BringUpConfig(), 458.0)
    assert how[-1] == "chained" and how[0] != "chained"
    for R_est, t in zip(R, stamps[1:], strict=True):
        err = np.degrees(Rotation.from_matrix(R_est.T @ truth[t]).magnitude())
        assert err < 0.1, (t, err, how)


def test_a_window_whose_tracks_do_not_last_is_refused_by_reason():
    cfg = BringUpConfig()
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.5, 0.5, (100, 2))
    ids = np.arange(100)
    sets = [(0, ids, xy), (1, ids[:20], xy[:20])]
    res = _two_view_rotations(sets, [0, 1], cfg, 458.0)
    assert isinstance(res, Rejection) and res.reason == "two_view_too_few_tracks"
    sets = [(0, ids, xy), (1, ids, rng.uniform(-0.5, 0.5, (100, 2)))]     # the same ids, random places
    res = _two_view_rotations(sets, [0, 1], cfg, 458.0)
    assert isinstance(res, Rejection) and res.reason == "two_view_failed"
    bu = HandEyeBringUp(None, cfg, focal_px=458.0)
    assert bu.on_result(res, 0) is False and bu.report.rejections == {"two_view_failed": 1}


@pytest.mark.slow
def test_handeye_bringup_then_tracking_with_online_calibration():
    rec = SimRecording.from_preset(SimConfig(preset="aggressive", seconds=16.0, seed=4))
    cam = rec.rig.camera
    withheld = rec.rig.replace(T_IC=None, time_offset_s=None)
    model = EmulatedDA3(rec.gt_source, cam.K, cam.width, cam.height, preset="base", seed=2)
    cfg = DavioConfig()
    pipe = VioPipeline(withheld, model, replace(cfg, mapping=replace(cfg.mapping, enabled=False)))
    Scheduler(FastClock(0.5)).run(rec.events(), pipe)
    rep = pipe.report()
    assert rep["bringup"]["R_IC"] is not None, rep["bringup"]
    R_est = np.array(rep["bringup"]["R_IC"])
    err = np.degrees(Rotation.from_matrix(R_est.T @ rec.rig.T_IC[:3, :3]).magnitude())
    print(f'R_IC error {err:.2f} deg after {rep["bringup"]["windows_used"]} windows')
    assert err < 2.0
    assert pipe.config.msckf.calib_extrinsics and pipe.config.msckf.calib_time_offset
    assert np.allclose(pipe.rig.T_IC[:3, 3], 0.0) and pipe.rig.time_offset_s == 0.0
    assert len(pipe.published) > 20


def _bring_up(events, gyro_scale=1.0) -> HandEyeBringUp:
    """Drive a model-free bring-up with synthetic rig events (runtime.bringup's own loop, no pipeline)."""
    from runtime.events import ImuSample

    bu = HandEyeBringUp(None, BringUpConfig(), focal_px=458.0)
    for e in events:
        if e[0] == "imu":
            bu.on_imu(ImuSample(e[1], np.asarray(e[2]) * gyro_scale, np.array([0.0, 0.0, 9.81])))
        else:
            bu.on_tracks(e[1], e[2], e[3])
            job = bu.next_job()
            if job is not None and bu.on_result(job(), e[1]):
                break
    return bu


def test_a_model_free_bringup_recovers_a_known_rotation_and_names_a_deg_per_second_gyro():
    from rig_synth import R_IC_SYN, synthetic_rig_events, turning

    events = synthetic_rig_events(R_IC_SYN, turning, seconds=9.0)
    bu = _bring_up(events)
    assert bu.done, bu.report
    err = np.degrees(Rotation.from_matrix(bu.result.R_IC.T @ R_IC_SYN).magnitude())
    assert err < 0.1, err
    bu = _bring_up(events, gyro_scale=np.degrees(1.0))
    assert not bu.done and bu.report.rejections.get("gyro_scale", 0) >= 5
    assert "deg/s" in bu.report.rejection_first["gyro_scale"]


def test_a_hand_eye_fit_that_explains_nothing_is_refused():
    """Camera and IMU rotations drawn independently: no rotation fits them; without the RMS bound the
    validation (2.5x the fit's own RMS) passed such a fit."""
    from runtime.ffinit.handeye import RotationWindow

    rng = np.random.default_rng(3)
    bu = HandEyeBringUp(None, BringUpConfig(), focal_px=458.0)
    for _ in range(9):
        R_c = Rotation.from_rotvec(rng.normal(0, 0.3, (4, 3))).as_matrix()
        R_i = Rotation.from_rotvec(rng.normal(0, 0.3, (4, 3))).as_matrix()
        done = bu.on_result(RotationWindow(R_c, R_i, np.repeat(np.eye(3)[None], 4, 0), np.zeros(3)), 0)
    assert not done and bu.report.rejections == {"handeye_poor_fit": 1}
    assert bu.report.fit_rms_deg > BringUpConfig().max_fit_rms_deg


def test_a_shaken_rig_is_not_taken_for_a_deg_per_second_gyro():
    """A 20 deg, 2.5 Hz shake on a slow turn: the gyro's path over a 0.8 s window passes 150 deg, about 20x
    the camera's rotation; the net rotation decides (the path alone refused these windows as gyro_scale)."""
    from rig_synth import R_IC_SYN, synthetic_rig_events

    def shaken(t):
        shake = np.radians(20) * 2 * np.pi * 2.5 * np.cos(2 * np.pi * 2.5 * t)
        return np.array([shake, 0.1 + 0.05 * np.sin(0.7 * t), 0.12])

    bu = _bring_up(synthetic_rig_events(R_IC_SYN, shaken, seconds=9.0))
    assert "gyro_scale" not in bu.report.rejections, bu.report
    assert bu.done
