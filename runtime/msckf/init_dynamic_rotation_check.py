"""Does the camera turn as the gyro says? The dynamic initializer's check, before its solves, that the
camera's rotation between neighbouring keyframes (two-view fits of the common tracks) matches the gyro's
through the rig's camera-IMU rotation, for the two rig mistakes that break every solve:

- a gyroscope logging deg/s (or at a wrong full scale) turns many times as far as the camera
  (`runtime.ffinit.gyro_scale.gyro_camera_ratio`: the net rotation angle, or the gyro's path where the net
  rotation may have wrapped);
- a camera-IMU rotation that is not the rig's (T_cam_imu given as T_imu_cam) turns by the same angle as the
  camera about another axis.

A pair whose camera fit turns farther than its gyro is not judged: over a short baseline a two-view fit can
take part of the translation for rotation (measured 10-15 deg too much on the MH_03 simulation's first
seconds), which neither mistake produces. On such a rig the linear solve and the refinement cost 0.3-1.5 s
per frame and fail anyway (BENCHMARKS.md "The dynamic initializer on a wrong rig"). Not in OpenVINS.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from runtime.ffinit.gyro_scale import gyro_camera_ratio
from runtime.geometry import so3_log
from runtime.geometry.two_view import two_view_rotation
from runtime.imu import Preintegration
from runtime.msckf.init_dynamic_window import Frame

SAME_ANGLE = 0.25
"""Camera and gyro angles within this fraction of the larger turn by the same angle (an axis mistake keeps
the angle: R_IC R R_IC^T turns as far as R)."""


@dataclass(frozen=True)
class RotationAgreement:
    """Keyframe pairs measured (a two-view rotation found), those that show a rig mistake (`gyro_scale` or
    `axis`), and the median camera-gyro difference (rad; nan without a measured pair)."""

    measured: int
    gyro_scale: int
    axis: int
    median_rad: float

    @property
    def disagreeing(self) -> int:
        return self.gyro_scale + self.axis


def rotation_agreement(keyframes: list[Frame], between: list[Preintegration], imu_t_ns: np.ndarray,
                       gyro: np.ndarray, R_IC: np.ndarray, focal_px: float, min_matches: int,
                       max_residual_rad: float, max_ratio: float = 15.0,
                       min_gyro_rad: float = np.radians(5.0)) -> RotationAgreement:
    """Compare each neighbouring keyframe pair's camera rotation with its preintegrated gyro rotation.

    Args:
        keyframes: K frames (t_ns, ids, uv, xy) with normalized camera coordinates xy.
        between: K-1 preintegrations between neighbouring keyframes (at the bias guess; IMU clock).
        imu_t_ns, gyro: the IMU samples (N,) and (N, 3) rad/s the preintegrations used.
        R_IC: (3, 3) the rig's camera-to-IMU rotation.
        focal_px: focal length, px (the two-view fits' 1 px threshold).
        min_matches: a pair needs this many common tracks supporting its rotation.
        max_residual_rad: camera and gyro rotations of the same angle farther apart than this (rad) show an
            axis mistake.
        max_ratio: a gyro turning more than this many times as far as the camera (and more than
            `min_gyro_rad`) shows a scale mistake.
    """
    residuals, scale, axis = [], 0, 0
    for k in range(len(keyframes) - 1):
        _, ids_a, _, xy_a = keyframes[k]
        _, ids_b, _, xy_b = keyframes[k + 1]
        _, ia, ib = np.intersect1d(ids_a, ids_b, return_indices=True)
        fit = two_view_rotation(xy_a[ia], xy_b[ib], 1.0 / focal_px, min_inliers=min_matches)
        if fit is None:
            continue
        pre = between[k]
        R_vis = R_IC @ fit.R_BA.T @ R_IC.T        # the IMU's rotation R_{Ia Ib} the camera saw
        residual = float(np.linalg.norm(so3_log(pre.dR.T @ R_vis)))
        camera = float(np.linalg.norm(so3_log(fit.R_BA)))
        net = float(np.linalg.norm(so3_log(pre.dR)))
        ratio = gyro_camera_ratio(imu_t_ns, gyro, pre.t0_ns, pre.t1_ns, pre.dR, max(np.degrees(camera), 1e-9))
        residuals.append(residual)
        if ratio > max_ratio and ratio * camera > min_gyro_rad:
            scale += 1
        elif residual > max_residual_rad and abs(camera - net) <= SAME_ANGLE * max(camera, net):
            axis += 1
    r = np.asarray(residuals)
    return RotationAgreement(len(r), scale, axis, float(np.median(r)) if len(r) else float("nan"))
