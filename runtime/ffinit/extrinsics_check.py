"""Is the rig's camera–IMU rotation the one the motion shows? Asked of a window the DA3–gyro alignment
refused (`gyro_bias_step`, `rotation_inconsistent`).

A wrong R_IC (most often T_cam_imu given where T_imu_cam belongs, or the reverse) makes every window's
DA3 and gyro rotations disagree, so the start-up refuses them for a reason that does not name the cause,
and a filter started at rest diverges once the rig turns. A hand-eye fit on the refused window
(`runtime.ffinit.handeye`, as the calibration-withheld bring-up does over several windows) tells the two
apart: the window is refused as `extrinsics_rotation` instead, saying by how much and whether the fit is
the rig's rotation inverted, when a rotation at least `FFInitConfig.extrinsics_check_deg` from the rig's
fits the window within `extrinsics_check_rms_deg`, with a plausible gyro bias, and
`extrinsics_check_ratio` times better than the rig's own rotation does (with the alignment's bias step).
The ratio, not an absolute bar, separates the two cases as DA3's rotation errors grow: both fits then
take up DA3's noise, while a wrong rotation leaves the rig's degrees off.
"""
from __future__ import annotations

import numpy as np

from runtime.ffinit.config import FFInitConfig
from runtime.ffinit.gyro_bias import rotation_residuals
from runtime.ffinit.handeye import HandEyeResult, RotationWindow, estimate_handeye
from runtime.ffinit.window import InitWindow, Rejection
from runtime.geometry import so3_log


def rotation_angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle (degrees) of the rotation between R_a and R_b."""
    return float(np.degrees(np.linalg.norm(so3_log(np.asarray(R_a).T @ np.asarray(R_b)))))


def check_extrinsic_rotation(window: InitWindow, cfg: FFInitConfig, dbg: np.ndarray | None = None,
                             bg_ref: np.ndarray | None = None) -> Rejection | None:
    """An `extrinsics_rotation` Rejection when the window's rotations fit a camera–IMU rotation far from
    the rig's (module docstring), else None: the window rotates about one axis only, no rotation fits it
    well, the rig's is near the fit, or the rig's own rotation (with the alignment's gyro-bias step
    `dbg`, rad/s) fits nearly as well: then the bias or DA3's noise, not the rotation, is what is off
    (with one window and a free bias, a large bias can be traded for a rotated R_IC: a review found 8-13
    of 120 windows of a right rig with a 0.3 rad/s bias fitted 13-41 deg off, while the rig's rotation
    fitted them within 0.07-0.13 deg with the bias step). The fit's gyro bias must lie within
    `max_gyro_bias_change` of `bg_ref` (the bias before the alignment; default: the window's)."""
    if window.num_images < 3:
        return None
    r = rotation_residuals(window, np.zeros(3) if dbg is None else np.asarray(dbg, float))
    rig_rms_deg = float(np.degrees(np.sqrt(np.mean(np.sum(r ** 2, axis=1)))))
    rw = RotationWindow(np.array([im.R_C0Ci for im in window.images[1:]]), window.R_I0Ii[1:],
                        window.J_R_bg[1:], np.asarray(window.bg, float))
    fit = estimate_handeye([rw], bg0=window.bg)
    if not isinstance(fit, HandEyeResult):
        return None
    off_deg = rotation_angle_deg(window.R_IC, fit.R_IC)
    bias_step = np.linalg.norm(fit.bg - (window.bg if bg_ref is None else bg_ref))
    if not (fit.rms_deg <= cfg.extrinsics_check_rms_deg and off_deg >= cfg.extrinsics_check_deg
            and rig_rms_deg >= cfg.extrinsics_check_ratio * fit.rms_deg
            and bias_step <= cfg.max_gyro_bias_change):
        return None
    inverted = rotation_angle_deg(window.R_IC.T, fit.R_IC) <= cfg.extrinsics_check_deg / 2
    return Rejection("extrinsics_rotation",
                     f"the rig's camera-IMU rotation is {off_deg:.1f} deg from the one this window's motion "
                     f"fits ({fit.rms_deg:.3f} deg RMS, the rig's {rig_rms_deg:.2f})"
                     + (": the rig's rotation inverted - T_cam_imu given as T_imu_cam, or the reverse?"
                        if inverted else ""))
