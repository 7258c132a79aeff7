"""A recorded tracking run with the odometry's error scaled by k (`davio bench trajectory --error-scales`).

Does the submap graph's share of the correction depend on how large the odometry's error is? The rows of
`--error-scales` answer it on one tracking run, keeping the error's structure and changing only its size:
every published pose and every mapping window's camera pose becomes

    p' = p_true + k (p_est - p_true),    R' = Exp(k Log(R_est R_true^T)) R_true

for the IMU pose, in the world frame W of the truth, after the segment's published positions are put on
the truth by a position + yaw fit (both frames are gravity-aligned, so the odometry frame O stays
gravity-aligned), and is then moved back into O; a window's camera pose follows its IMU pose through T_IC.
(Exp(k Log(R_est R_true^T)) R_true = R_true Exp(k Log(R_true^T R_est)): a left or a right rotation error
scales alike.) k = 1 returns the run as recorded (to rounding), k = 0 the true poses; k = 2 doubles every
position and rotation error of the run. The images, the mapping schedule and the emulated DA3 are
those of the recorded run; only the poses the mapper is given, and the odometry it corrects, change.
Velocities are left as the filter published them (the replay does not use them).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from runtime.errors import ConfigError, TrajectoryError
from runtime.geometry.so3 import rot_z, so3_exp, so3_log
from tools.benchmarks.trajectory_inputs import TrackingRun
from tools.benchmarks.trajectory_replay import odometry_poses
from tools.evaluation.align import posyaw

CameraPose = Callable[[int], np.ndarray]
"""The true T_WC (4,4) of the frame stamped t_ns (camera clock), e.g. `GroundTruthSource.camera_pose`."""


def parse_error_scales(spec: str | None) -> list[float]:
    """`--error-scales` "0.5,2" -> [0.5, 2.0]; None or "" -> []. Each must be a finite k >= 0, given once."""
    if not spec:
        return []
    out: list[float] = []
    for item in (x.strip() for x in spec.split(",")):
        if not item:
            raise ConfigError(f"--error-scales: empty entry in {spec!r}")
        try:
            k = float(item)
        except ValueError:
            raise ConfigError(f"--error-scales: {item!r} is not a number") from None
        if not np.isfinite(k) or k < 0:
            raise ConfigError(f"--error-scales: {item} must be finite and >= 0")
        k = abs(k)             # -0 -> 0
        if k in out:
            raise ConfigError(f"--error-scales: {item} is given twice")
        out.append(k)
    return out


def scale_pose_error(T_WX_est: np.ndarray, T_WX_true: np.ndarray, k: float) -> np.ndarray:
    """(4,4) the pose whose position and rotation errors against T_WX_true are k times those of T_WX_est
    (position error p_est - p_true in W, metres; rotation error Log(R_est R_true^T), rad)."""
    out = np.eye(4)
    out[:3, 3] = T_WX_true[:3, 3] + k * (T_WX_est[:3, 3] - T_WX_true[:3, 3])
    dphi = so3_log(T_WX_est[:3, :3] @ T_WX_true[:3, :3].T)
    out[:3, :3] = so3_exp(k * dphi) @ T_WX_true[:3, :3]
    return out


def _fit_T_WO(T_OI: np.ndarray, T_WI: np.ndarray) -> np.ndarray:
    """(4,4) the yaw + translation T_WO putting the estimates (N,4,4) on the truth: fitted on the positions
    (`posyaw`); where they fix no yaw (one pose, no horizontal motion) the yaw comes from the orientations
    (the yaw of sum_i R_WI_i R_OI_i^T) and the translation from the mean position offset."""
    T = np.eye(4)
    try:
        T[:3, :3], T[:3, 3] = posyaw(T_OI[:, :3, 3], T_WI[:, :3, 3])
    except TrajectoryError:
        M = np.einsum("nij,nkj->ik", T_WI[:, :3, :3], T_OI[:, :3, :3])
        T[:3, :3] = rot_z(np.arctan2(M[1, 0] - M[0, 1], M[0, 0] + M[1, 1]))
        T[:3, 3] = (T_WI[:, :3, 3] - T_OI[:, :3, 3] @ T[:3, :3].T).mean(axis=0)
    return T


def error_scaled_run(run: TrackingRun, camera_pose: CameraPose, T_IC: np.ndarray, k: float) -> TrackingRun:
    """A copy of `run` whose published poses and window camera poses carry k times the run's error (module
    docstring); each filter segment gets its own O-to-W fit. The input run is not modified.

    Args:
        run: the recorded tracking run (trajectory_inputs.record_tracking).
        camera_pose: the truth, T_WC at a camera stamp (ns).
        T_IC: (4,4) the rig's camera pose in the IMU frame.
        k: the error multiplier (>= 0).
    """
    if not np.isfinite(k) or k < 0:
        raise ConfigError(f"error scale must be finite and >= 0, got {k}")
    T_CI = np.linalg.inv(T_IC)
    T_OI = odometry_poses(run.published)
    T_WI_true = np.array([camera_pose(int(p.t_cam_ns)) @ T_CI for p in run.published]).reshape(-1, 4, 4)
    segs = np.array([p.segment for p in run.published], np.int64)
    T_WO: dict[int, np.ndarray] = {}
    for s in np.unique(segs):
        idx = np.nonzero(segs == s)[0]
        T_WO[int(s)] = _fit_T_WO(T_OI[idx], T_WI_true[idx])

    def scaled(T_OI_est: np.ndarray, T_WI: np.ndarray, segment: int) -> np.ndarray:
        W = T_WO.get(int(segment))
        if W is None:          # a window of a segment that published nothing: no fit, left as recorded
            return T_OI_est
        return np.linalg.inv(W) @ scale_pose_error(W @ T_OI_est, T_WI, k)

    published = []
    for i, p in enumerate(run.published):
        T = scaled(T_OI[i], T_WI_true[i], p.segment)
        published.append(replace(p, R_OI=T[:3, :3].copy(), p_OI=T[:3, 3].copy()))
    slots = []
    for slot in run.slots:
        w = slot.window
        T_OC = np.array([scaled(w.T_OC[j] @ T_CI, camera_pose(int(f.t_ns)) @ T_CI, w.segment) @ T_IC
                         for j, f in enumerate(w.frames)]).reshape(-1, 4, 4)
        slots.append(replace(slot, window=replace(w, T_OC=T_OC)))
    return replace(run, published=published, slots=slots)
