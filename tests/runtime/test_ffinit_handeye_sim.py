"""Hand–eye on simulated data: emulated-DA3 relative rotations of rendered windows and the
simulator's noisy IMU recover a withheld camera–IMU rotation within 1 degree."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from drivers.sim import SimConfig, SimRecording
from models.emulated_da3 import EmulatedDA3
from runtime.ffinit.handeye import RotationWindow, estimate_handeye, validate_handeye
from runtime.ffinit.window import Rejection
from runtime.imu import Preintegrator


@pytest.mark.slow
def test_handeye_recovers_withheld_rotation_on_simulated_recording():
    rec = SimRecording.from_preset(SimConfig(preset="aggressive", seconds=12.0, seed=4))
    cam, imu = rec.rig.camera, rec.imu
    R_IC_true = rec.rig.T_IC[:3, :3]
    model = EmulatedDA3(rec.gt_source, cam.K, cam.width, cam.height, preset="base", seed=5)
    pre = Preintegrator(np.zeros(3), np.zeros(3))

    def window(first: int) -> RotationWindow:
        frames = [rec.render(first + 4 * k)[0] for k in range(5)]
        pred = model.predict(frames)
        R_c, R_i, J = [], [], []
        for k in range(1, 5):
            R_c.append(pred.T_CW[k][:3, :3].T)  # R_C0Ck from the predicted world(=C0)-to-camera pose
            p = pre.integrate(imu.t_ns, imu.gyro, imu.accel, frames[0].t_ns, frames[k].t_ns)
            R_i.append(p.dR)
            J.append(p.J_R_bg)
        return RotationWindow(np.array(R_c), np.array(R_i), np.array(J), np.zeros(3))

    fit = [window(f) for f in range(10, 190, 10)]  # overlapping windows, one second of data apart
    res = estimate_handeye(fit)
    assert not isinstance(res, Rejection), res
    err = np.degrees(Rotation.from_matrix(res.R_IC.T @ R_IC_true).magnitude())
    print(f'R_IC error {err:.3f} deg, fit RMS {res.rms_deg:.2f} deg')
    assert err < 1.0
    ok, rms = validate_handeye(res, window(200))
    assert ok, rms
    np.testing.assert_allclose(res.bg, rec.groundtruth().bg[0], atol=0.02)
