"""`why_nothing_published`: the reason a run that published nothing gives, from its counters."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from tools.run_outcome import why_nothing_published

SCHED = SimpleNamespace(imu_samples=800, frames=40, sensor_s=4.0)


def test_a_started_filter_without_imu_around_its_frames_names_the_time_offset() -> None:
    report = {"tracking": {}, "filter": {"initialized": True, "frames_processed": 0, "frames_no_imu": 20}}
    why = why_nothing_published(report, {"streams": {}}, SCHED)
    assert why.startswith("the filter started but processed no frame (20 frames had no IMU data")
    assert "time_offset_s / timeshift_cam_imu" in why


def test_a_filter_that_processed_frames_adds_nothing_and_an_empty_report_says_so() -> None:
    report = {"tracking": {}, "filter": {"initialized": True, "frames_processed": 12, "frames_no_imu": 3}}
    assert why_nothing_published(report, {"streams": {}}, SCHED) == "no reason recorded"
    started = {"tracking": {}, "filter": {"initialized": True, "frames_processed": 0, "frames_no_imu": 0}}
    assert why_nothing_published(started, None, SCHED) == "the filter started but processed no frame"


def test_a_started_but_unconfirmed_candidate_is_named() -> None:
    report = {"tracking": {}, "startup": {"ff_requests": 1, "ff_accepted": 1, "candidates_started": 1,
                                          "candidates_selected": 0, "candidates_abandoned": 0}}
    why = why_nothing_published(report, None, SCHED)
    assert "1 feed-forward candidate(s) started, none confirmed" in why and "abandoned" not in why
    report["startup"]["candidates_diverged"] = 1
    assert "(1 diverged)" in why_nothing_published(report, None, SCHED)


def test_a_wrong_rig_named_by_the_checks_is_part_of_the_reason() -> None:
    report = {"tracking": {}, "rig_check": {"gyro_scale": "the gyroscope turns 57.9x as far",
                                            "extrinsics_rotation": None}}
    assert why_nothing_published(report, None, SCHED) == "GYROSCOPE SCALE: the gyroscope turns 57.9x as far"
    suspect = {"tracking": {}, "rig_check": {"extrinsics_suspect": "6.0 deg from the rig's"}}
    assert why_nothing_published(suspect, None, SCHED) == "CAMERA-IMU ROTATION?: 6.0 deg from the rig's"
    bu = {"R_IC": None, "windows_used": 2, "rejections": {"gyro_scale": 19, "two_view_too_few_tracks": 2},
          "rejection_first": {"gyro_scale": "57.1x as far as the camera"}}
    report = {"tracking": {}, "bringup": bu}
    assert why_nothing_published(report, None, SCHED) == "GYROSCOPE SCALE: 57.1x as far as the camera"
    # a few gyro_scale windows among many others, or a completed bring-up: the gyro is not blamed
    bu["rejections"]["gyro_scale"] = 2
    why = why_nothing_published(report, None, SCHED)
    assert why.startswith("the hand-eye bring-up never completed (2 windows held, rejections: gyro_scale x2")
    bu["rejections"] = {"handeye_poor_fit": 9}
    assert "point at the gyroscope's scale or a large" in why_nothing_published(report, None, SCHED)
    bu["R_IC"] = np.eye(3).tolist()
    assert why_nothing_published(report, None, SCHED) == "no reason recorded"
