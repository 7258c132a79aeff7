"""The model-free rig checks (runtime.rig_check) on a rendered recording with a known rig: the right rig
raises nothing, a gyroscope logging deg/s and an inverted camera-IMU rotation are each named (the same
tracks and IMU fed to the three checks, as `davio bench rig-checks-two-view` does); and in the pipeline,
the check runs only without a model."""
from __future__ import annotations

import numpy as np
import pytest
from rig_synth import R_IC_SYN, synthetic_rig_events, turning

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
    assert r["extrinsics_rotation"] is None and r["extrinsics_fit_deg"] < 5.0
    assert r["extrinsics_suspect"] is None
    assert r["rig_residual_median_deg"] < 1.0


@pytest.mark.slow
def test_a_camera_imu_rotation_a_few_degrees_off_is_suspected_not_named(reports):
    """5 deg off about the optical axis: below the finding (10 deg), it reset the filter again and again
    with a wrong scale, and nothing named the rig."""
    r = reports["5deg"]
    assert r["extrinsics_rotation"] is None and r["gyro_scale"] is None
    assert r["extrinsics_fit_deg"] == pytest.approx(5.0, abs=1.0)
    assert r["extrinsics_rig_rms_deg"] >= RigCheckConfig().suspect_ratio * r["extrinsics_fit_rms_deg"]
    assert "fit a camera-IMU rotation" in r["extrinsics_suspect"]


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


def _feed(check, events):
    for e in events:
        if e[0] == "imu":
            check.on_imu(e[1], e[2])
        else:
            check.on_tracks(e[1], e[2], e[3])
    return check.report


def test_the_check_stops_after_its_spans_and_counts_what_it_could_not_judge():
    check = TwoViewRigCheck(R_IC_SYN, 0.0, 458.0, RigCheckConfig(max_pairs=5))
    rep = _feed(check, synthetic_rig_events(R_IC_SYN, turning))
    assert rep.done and rep.spans_judged == 5 and rep.gyro_scale is None
    assert 0.95 < rep.gyro_ratio_median < 1.05
    # a NaN sample is dropped and counted, not an error; an IMU that starts late leaves spans uncovered
    rep = _feed(TwoViewRigCheck(R_IC_SYN, 0.0, 458.0),
                synthetic_rig_events(R_IC_SYN, turning, nan_at_s=3.0, imu_from_s=2.2))
    assert rep.error is None and rep.imu_dropped == 1
    assert rep.spans_without_imu >= 1 and rep.spans_judged >= 8
    assert rep.extrinsics_rotation is None and rep.extrinsics_fit_deg < 0.5


def test_an_oscillating_rig_is_not_taken_for_a_deg_per_second_gyro():
    """A 2 Hz, +-10 deg oscillation on a slow turn: the gyro's path over half a second is many times the
    camera's net rotation, the gyro's net rotation is not."""
    def wobble(t):
        return np.array([np.radians(10) * 2 * np.pi * 2 * np.cos(2 * np.pi * 2 * t), 0.05, 0.08])

    rep = _feed(TwoViewRigCheck(R_IC_SYN, 0.0, 458.0), synthetic_rig_events(R_IC_SYN, wobble))
    assert rep.spans_judged >= 5 and rep.gyro_scale is None and rep.gyro_ratio_median < 1.5


def test_the_pipeline_checks_the_rig_only_without_a_model():
    from models.emulated_da3 import EmulatedDA3
    from runtime.pipeline import VioPipeline

    rec = SimRecording.from_preset(SimConfig(preset="euroc", seconds=2.0))
    without = VioPipeline(rec.rig, None)
    assert without.rig_check is not None and "rig_check" in without.report()
    cam = rec.rig.camera
    model = EmulatedDA3(rec.gt_source, cam.K, cam.width, cam.height, preset="base")
    with_model = VioPipeline(rec.rig, model)
    assert with_model.rig_check is None and "rig_check" not in with_model.report()
    assert VioPipeline(rec.rig.replace(T_IC=None), None).rig_check is None   # a bring-up has no rig to check


def test_the_rig_check_and_bring_up_sections_of_a_config_file_reach_the_pipeline(tmp_path):
    """`[rig_check]` and `[bringup]` of a config.toml are read, checked (the key named) and used."""
    from runtime.config import load_davio_config
    from runtime.errors import ConfigError
    from runtime.pipeline import VioPipeline

    rec = SimRecording.from_preset(SimConfig(preset="euroc", seconds=2.0))
    path = tmp_path / "config.toml"
    path.write_text("[rig_check]\nenabled = false\n\n[bringup]\nmin_rotation_deg = 7.5\nfit_windows = 4\n")
    cfg = load_davio_config(path)
    assert VioPipeline(rec.rig, None, config=cfg).rig_check is None
    bring_up = VioPipeline(rec.rig.replace(T_IC=None), None, config=cfg).bringup
    assert bring_up.cfg.min_rotation_deg == 7.5 and bring_up.cfg.fit_windows == 4
    assert bring_up.report.min_rotation_deg == 7.5        # the report says which bound skipped a window
    path.write_text("[rig_check]\nspan_s = 1.0\nmin_pairs_extrinsics = 3\n")
    check = VioPipeline(rec.rig, None, config=load_davio_config(path)).rig_check
    assert check.cfg.span_s == 1.0 and check.cfg.min_pairs_extrinsics == 3
    path.write_text("[rig_check]\nspan_s = 0.0\n")
    with pytest.raises(ConfigError, match="rig_check.span_s"):
        load_davio_config(path)
