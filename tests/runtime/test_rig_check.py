"""The model-free rig checks (runtime.rig_check) on a rendered recording with a known rig: the right rig
raises nothing, a gyroscope logging deg/s and an inverted camera-IMU rotation are each named (the same
tracks and IMU fed to the three checks, as `davio bench rig-checks-two-view` does); and in the pipeline,
the check runs only without a model."""
from __future__ import annotations

import numpy as np
import pytest

from drivers.sim import SimConfig, SimRecording
from runtime.rig_check import RigCheckConfig, TwoViewRigCheck
from tools.benchmarks.rig_checks_two_view import measure


@pytest.fixture(scope="module")
def reports() -> dict:
    """14 s of the euroc preset at 10 Hz (turning about more than one axis)."""
    return measure(SimRecording.from_preset(SimConfig(preset="euroc", seconds=14.0, seed=1,
                                                      camera_rate_hz=10.0)))


@pytest.mark.slow
def test_the_right_rig_raises_nothing(reports):
    r = reports["right"]
    assert r["spans_judged"] >= 8 and r["error"] is None
    assert 0.8 < r["gyro_ratio_median"] < 1.3 and r["gyro_scale"] is None
    assert r["extrinsics_rotation"] is None and r["extrinsics_fit_deg"] < 2.0
    assert r["rig_residual_median_deg"] < 1.0


@pytest.mark.slow
def test_a_gyroscope_in_deg_per_second_is_named(reports):
    r = reports["deg/s"]
    assert 40 < r["gyro_ratio_median"] < 80
    assert "deg/s" in r["gyro_scale"]
    assert r["extrinsics_rotation"] is None      # not judged once the gyro is known wrong


@pytest.mark.slow
def test_an_inverted_camera_imu_rotation_is_named(reports):
    r = reports["inverted"]
    assert r["gyro_scale"] is None                 # the ratio of angles does not see the rotation
    assert "inverted" in r["extrinsics_rotation"]
    assert r["extrinsics_rig_rms_deg"] > 10 * r["extrinsics_fit_rms_deg"]


def test_the_check_stops_after_its_spans_and_waits_for_the_imu():
    rng = np.random.default_rng(0)
    check = TwoViewRigCheck(np.eye(3), 0.0, 458.0, RigCheckConfig(span_s=0.5, every_s=1.0))
    xy = rng.uniform(-0.4, 0.4, (60, 2))
    ids = np.arange(60)
    check.on_tracks(0, ids, xy)
    check.on_tracks(500_000_000, ids, xy)        # due, but no IMU yet: pending, not judged
    assert check.report.spans_judged == 0 and check._pending is not None
    for k in range(0, 60):                          # the IMU arrives: a still camera, not judged as turning
        check.on_imu(k * 10_000_000, (0.0, 0.0, 0.0))
    assert check._pending is None and check.report.spans_still == 1
    check.on_tracks(400_000_000, ids, xy)          # out of order: ignored
    check.on_tracks(600_000_000, ids[:0], xy[:0])  # no features: ignored
    assert [t for t, _, _ in check._tracks] == [0, 500_000_000]


def test_the_pipeline_checks_the_rig_only_without_a_model():
    from models.emulated_da3 import EmulatedDA3
    from runtime.pipeline import VioPipeline

    rec = SimRecording.from_preset(SimConfig(preset="euroc", seconds=2.0))
    assert VioPipeline(rec.rig, None).rig_check is not None
    cam = rec.rig.camera
    model = EmulatedDA3(rec.gt_source, cam.K, cam.width, cam.height, preset="base")
    assert VioPipeline(rec.rig, model).rig_check is None
    assert "rig_check" not in VioPipeline(rec.rig, model).report()
