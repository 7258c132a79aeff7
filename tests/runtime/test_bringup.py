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
from runtime.config import DavioConfig
from runtime.errors import ConfigError
from runtime.pipeline import VioPipeline
from runtime.scheduler import FastClock, Scheduler


def test_withheld_extrinsics_without_a_model_is_a_clear_error():
    rig = SimRecording.from_preset(SimConfig(preset="euroc", seconds=3.0)).rig.replace(T_IC=None)
    with pytest.raises(ConfigError, match="withheld"):
        VioPipeline(rig, None)


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
