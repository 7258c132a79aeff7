"""The camera–IMU rotation check of a refused start-up window (runtime/ffinit/extrinsics_check.py) on
synthetic windows with exact rotations: the rig's rotation inverted, rotated, right, or unobservable."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from runtime.ffinit.config import FFInitConfig
from runtime.ffinit.extrinsics_check import check_extrinsic_rotation, rotation_angle_deg
from runtime.ffinit.initializer import solve_window
from tests.runtime.ffinit_synth import R_IC_EUROC, make_window


def _rotated(deg: float, axis=(0.2, 0.9, -0.4)) -> np.ndarray:
    a = np.asarray(axis) / np.linalg.norm(axis)
    return Rotation.from_rotvec(np.radians(deg) * a).as_matrix() @ R_IC_EUROC


def test_the_rig_rotation_inverted_is_named():
    window, _ = make_window("tumbling")
    rej = check_extrinsic_rotation(replace(window, R_IC=R_IC_EUROC.T), FFInitConfig())
    assert rej is not None and rej.reason == "extrinsics_rotation" and "inverted" in rej.detail
    assert f"{rotation_angle_deg(R_IC_EUROC.T, R_IC_EUROC):.1f} deg" in rej.detail   # 178.x deg


@pytest.mark.parametrize("deg, named", [(0.0, False), (5.0, False), (30.0, True), (90.0, True)])
def test_a_rotated_rig_is_named_beyond_the_bound_and_never_called_inverted(deg, named):
    window, _ = make_window("tumbling")
    rej = check_extrinsic_rotation(replace(window, R_IC=_rotated(deg)), FFInitConfig())
    assert (rej is not None) == named
    if named:
        assert f"{deg:.1f} deg" in rej.detail and "inverted" not in rej.detail


def test_no_diagnosis_when_the_window_cannot_tell():
    cfg = FFInitConfig()
    # rotation about one axis: the hand-eye rotation is unobservable
    window, _ = make_window("pure_rotation")
    assert check_extrinsic_rotation(replace(window, R_IC=R_IC_EUROC.T), cfg) is None
    # DA3 rotations 2 deg off: no rotation fits within extrinsics_check_rms_deg, whatever the rig's
    window, _ = make_window("tumbling", rot_noise_deg=2.0, seed=3)
    assert check_extrinsic_rotation(replace(window, R_IC=_rotated(30.0)), cfg) is None
    assert check_extrinsic_rotation(replace(window, R_IC=_rotated(30.0)),
                                    replace(cfg, extrinsics_check_rms_deg=5.0)) is not None


def test_the_solve_refuses_an_inverted_rig_for_that_reason():
    window, _ = make_window("tumbling")
    assert not hasattr(solve_window(window, FFInitConfig()), "reason")            # the right rig: a state
    rej = solve_window(replace(window, R_IC=R_IC_EUROC.T), FFInitConfig())
    assert rej.reason == "extrinsics_rotation"
    off = solve_window(replace(window, R_IC=R_IC_EUROC.T), FFInitConfig(extrinsics_check_deg=180.0))
    assert off.reason in ("gyro_bias_step", "rotation_inconsistent")         # the check out of reach
