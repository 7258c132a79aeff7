"""Gyro bias from vision: align preintegrated keyframe rotations with essential-matrix rotations."""

from __future__ import annotations

import numpy as np

from runtime.geometry import so3_log
from runtime.imu import Preintegration
from runtime.msckf.init_dynamic_window import Frame


def visual_gyro_bias(
    keyframes: list[Frame],
    between: list[Preintegration],
    bg0: np.ndarray,
    R_IC: np.ndarray,
    focal_px: float,
    min_matches: int,
    max_residual_rad: float,
) -> np.ndarray | None:
    """Gyro bias (3,) rad/s that makes the gyro rotations between keyframes agree with the camera's.

    For each neighbouring keyframe pair, RANSAC on the essential matrix of the common tracks
    (normalized coordinates, threshold 1 px = 1 / focal_px) gives the camera rotation, turned into
    the IMU rotation R_vis = R_{Ik Ik+1} with R_IC. With J_R_bg the preintegrated rotation's bias
    Jacobian, Log(dR^T R_vis) = J_R_bg dbg is solved in the least-squares sense (VINS-Mono style)
    and bg0 + dbg returned.

    Args:
        keyframes: K frames (t_ns, ids, uv, xy) with normalized camera coordinates xy.
        between: K-1 preintegrations between neighbouring keyframes, integrated at the bias bg0.
        bg0: (3,) gyro bias of ``between``, rad/s.
        R_IC: (3, 3) camera-to-IMU rotation.
        focal_px: focal length, px (scales the RANSAC threshold).
        min_matches: a pair needs this many finite common tracks and RANSAC inliers.
        max_residual_rad: a pair whose visual and gyro rotations differ by more is left out, rad.

    Returns:
        The bias, or None when fewer than two pairs remain.
    """
    import cv2

    R_CI = R_IC.T
    rows_J, rows_r = [], []
    for k in range(len(keyframes) - 1):
        _, ids_a, _, xy_a = keyframes[k]
        _, ids_b, _, xy_b = keyframes[k + 1]
        common, ia, ib = np.intersect1d(ids_a, ids_b, return_indices=True)
        if common.size < min_matches:
            continue
        pa, pb = xy_a[ia], xy_b[ib]
        good = np.all(np.isfinite(pa), axis=1) & np.all(np.isfinite(pb), axis=1)
        pa, pb = pa[good], pb[good]
        if pa.shape[0] < min_matches:
            continue
        E, mask = cv2.findEssentialMat(pa, pb, np.eye(3), cv2.RANSAC, 0.999, 1.0 / focal_px)
        if E is None or E.shape != (3, 3):
            continue
        n_in, R_ba, _, _ = cv2.recoverPose(E, pa, pb, np.eye(3), mask=mask)
        if n_in < min_matches:
            continue
        # R_ba maps camera-a coordinates to camera b: R_{Cb Ca}; the IMU rotation R_{Ia Ib}
        R_vis = R_IC @ R_ba.T @ R_CI
        r = so3_log(between[k].dR.T @ R_vis)
        if np.linalg.norm(r) > max_residual_rad:
            continue
        rows_J.append(between[k].J_R_bg)
        rows_r.append(r)
    if len(rows_J) < 2:
        return None
    dbg = np.linalg.lstsq(np.concatenate(rows_J), np.concatenate(rows_r), rcond=None)[0]
    return bg0 + dbg
