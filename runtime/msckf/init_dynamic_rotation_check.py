"""Does the camera turn as the gyro says? The dynamic initializer's check, before its solves, that the
camera's rotation between neighbouring keyframes (two-view fits of the common tracks) agrees with the gyro's
through the rig's camera-IMU rotation. A gyroscope logging deg/s or a camera-IMU rotation that is not the
rig's (T_cam_imu given as T_imu_cam) contradicts it in every pair; the linear solve and the nonlinear
refinement then cost 0.3-1.5 s per frame and fail anyway (BENCHMARKS.md "The dynamic initializer on a
wrong rig"). Not in OpenVINS.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from runtime.geometry import so3_log
from runtime.geometry.two_view import two_view_rotation
from runtime.imu import Preintegration
from runtime.msckf.init_dynamic_window import Frame


@dataclass(frozen=True)
class RotationAgreement:
    """Keyframe pairs measured (a two-view rotation found), those whose camera and gyro rotations differ by
    more than the bound, and the median difference (rad; nan without a measured pair)."""

    measured: int
    disagreeing: int
    median_rad: float


def rotation_agreement(keyframes: list[Frame], between: list[Preintegration], R_IC: np.ndarray,
                       focal_px: float, min_matches: int, max_residual_rad: float, max_ratio: float = 15.0,
                       min_gyro_rad: float = np.radians(5.0)) -> RotationAgreement:
    """Compare each neighbouring keyframe pair's camera rotation with its preintegrated gyro rotation. A pair
    disagrees when the two differ by more than `max_residual_rad`, or when its gyro turns more than
    `min_gyro_rad` and more than `max_ratio` times as far as its camera: a gyroscope in deg/s over a pair
    that barely turns (0.2 deg) differs by less than the bound but turns 57 times as far.

    Args:
        keyframes: K frames (t_ns, ids, uv, xy) with normalized camera coordinates xy.
        between: K-1 preintegrations between neighbouring keyframes (at the bias guess).
        R_IC: (3, 3) the rig's camera-to-IMU rotation.
        focal_px: focal length, px (the two-view fits' 1 px threshold).
        min_matches: a pair needs this many common tracks supporting its rotation.
        max_residual_rad: a larger angle between the two rotations is a disagreement, rad.
        max_ratio: a gyro angle over this many times the camera's is a disagreement (past min_gyro_rad).
        min_gyro_rad: gyro angles below this are not judged by their ratio (noise), rad.
    """
    residuals, ratio_out = [], 0
    for k in range(len(keyframes) - 1):
        _, ids_a, _, xy_a = keyframes[k]
        _, ids_b, _, xy_b = keyframes[k + 1]
        _, ia, ib = np.intersect1d(ids_a, ids_b, return_indices=True)
        fit = two_view_rotation(xy_a[ia], xy_b[ib], 1.0 / focal_px, min_inliers=min_matches)
        if fit is None:
            continue
        R_vis = R_IC @ fit.R_BA.T @ R_IC.T        # the IMU's rotation R_{Ia Ib} the camera saw
        residual = float(np.linalg.norm(so3_log(between[k].dR.T @ R_vis)))
        gyro = float(np.linalg.norm(so3_log(between[k].dR)))
        camera = float(np.linalg.norm(so3_log(fit.R_BA)))
        residuals.append(residual)
        ratio_out += residual <= max_residual_rad and gyro > min_gyro_rad and gyro > max_ratio * camera
    r = np.asarray(residuals)
    return RotationAgreement(len(r), int(np.sum(r > max_residual_rad)) + ratio_out,
                             float(np.median(r)) if len(r) else float("nan"))
