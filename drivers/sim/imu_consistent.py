"""A ground truth that a replayed real IMU agrees with, for rendering EuRoC-trajectory recordings.

EuRoC-trajectory mode renders images along a real ground truth and replays the real IMU. The ground truth is
itself an estimate (motion capture or a laser tracker, fused) with short disagreements with the IMU that no
physical camera and IMU pair has, and images rendered from it move where the IMU does not:
- position jumps: MH_03_medium's ground truth (laser tracker) jumps 25 times by 5 mm to 8 cm within one 5 ms
  sample (8.1 cm at 35.395 s, a 17 m/s step the accelerometer never measured; the filter's landmarks then
  all miss by about 5 px at once, BENCHMARKS.md "Trajectory"), and 20 times by 2-5 mm (below a pixel; these
  stay);
- attitude spells: V1_02_medium's angular rate leaves the bias-corrected gyro by more than 2 deg/s on 2.6 %
  of its samples (up to 11 deg/s).

`remove_position_jumps` takes out single-sample velocity outliers (the trajectory stays continuous and keeps
its shape; later positions shift by the removed steps). `gyro_consistent_attitude` integrates the
bias-corrected gyro and holds it to the ground truth below about 1 / (2 pi smoothing_s) Hz:

    R_int(t_k+1) = R_int(t_k) Exp(0.5 (w_k + w_k+1 - bg_k - bg_k+1) dt_k),   R_int(t_0) = R_gt(t_0)
    delta(t) = Log(R_gt(t) R_int(t)^T),   delta_s = Gaussian(delta; smoothing_s)
    R(t) = Exp(delta_s(t)) R_int(t)

The rendered attitude then turns at the gyro's rate minus the ground truth's bias plus R_int^T d delta_s / dt,
a slowly varying term that the filter sees as part of the gyro bias. The result is the recording's truth.
"""
from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d, median_filter
from scipy.spatial.transform import Rotation

from drivers.sim.spline import interpolate_positions, interpolate_rotations
from runtime.errors import ConfigError, DataError
from runtime.geometry.trajectory import PoseTrajectory

DEFAULT_SMOOTHING_S = 1.0
"""Standard deviation of the Gaussian that holds the gyro's attitude to the ground truth, s."""

DEFAULT_MAX_STEP_SPEED_MPS = 1.0
"""A sample's velocity farther than this from the median of the 21 around it (+-50 ms) is a position jump,
m/s: a jump of 5 mm within a 5 ms sample is 1 m/s. Smooth motion stays well below: the median follows a
monotonic velocity exactly, and at a velocity extremum a MAV's 10 m/s^2 leaves it about 0.5 m/s off; EuRoC
V1_02's largest deviation is 0.055 m/s. MH_03's 20 smaller steps of 2-5 mm (0.4-1 m/s) stay."""

MAX_DRIFT_DEG = 20.0
"""Largest disagreement between the integrated gyro and the ground truth's attitude accepted, deg (EuRoC
V1_02 and MH_03: 0.7-0.8 deg over the whole sequence)."""

_STEP_WINDOW = 21
"""Samples in the median that a sample's velocity is compared with."""


def imu_consistent_groundtruth(traj: PoseTrajectory, t_imu_ns: np.ndarray, gyro: np.ndarray,
                               smoothing_s: float = DEFAULT_SMOOTHING_S,
                               max_step_speed_mps: float = DEFAULT_MAX_STEP_SPEED_MPS) -> PoseTrajectory:
    """`traj` without its position jumps, at the IMU stamps inside its span, with the gyro's attitude
    (`remove_position_jumps`, then `gyro_consistent_attitude`); meta records what was changed."""
    fixed, steps = remove_position_jumps(traj, max_step_speed_mps)
    out = gyro_consistent_attitude(fixed, t_imu_ns, gyro, smoothing_s)
    out.meta["position_jumps_removed"] = len(steps)
    out.meta["position_jumps_m"] = [round(float(np.linalg.norm(d)), 4) for d in steps]
    return out


def remove_position_jumps(traj: PoseTrajectory, max_step_speed_mps: float = DEFAULT_MAX_STEP_SPEED_MPS
                          ) -> tuple[PoseTrajectory, list[np.ndarray]]:
    """`traj` without its position jumps, and the removed steps ((3,) each, m).

    A sample interval whose velocity (position difference over time) is more than ``max_step_speed_mps``
    from the median velocity of the `_STEP_WINDOW` intervals around it is a jump: it moves by that median
    velocity instead, and every later position moves with it. Rotations, velocities and biases are kept."""
    if not (np.isfinite(max_step_speed_mps) and max_step_speed_mps > 0):
        raise ConfigError(f"max_step_speed_mps must be a positive number, got {max_step_speed_mps!r}")
    if len(traj) < _STEP_WINDOW + 2:
        return traj, []
    dt = np.diff(traj.t_ns).astype(np.float64) * 1e-9
    dp = np.diff(traj.p, axis=0)
    v = dp / dt[:, None]
    v_ref = median_filter(v, size=(_STEP_WINDOW, 1), mode="nearest")
    bad = np.linalg.norm(v - v_ref, axis=1) > max_step_speed_mps
    if not bad.any():
        return traj, []
    steps = [dp[k] - v_ref[k] * dt[k] for k in np.flatnonzero(bad)]
    dp_fixed = dp.copy()
    dp_fixed[bad] = v_ref[bad] * dt[bad, None]
    p = np.concatenate([traj.p[:1], traj.p[0] + np.cumsum(dp_fixed, axis=0)])
    meta = dict(traj.meta or {})
    return PoseTrajectory(traj.t_ns, p, traj.R, traj.v, traj.bg, traj.ba, meta=meta), steps


def gyro_consistent_attitude(traj: PoseTrajectory, t_imu_ns: np.ndarray, gyro: np.ndarray,
                             smoothing_s: float = DEFAULT_SMOOTHING_S) -> PoseTrajectory:
    """T_WI at the IMU stamps inside ``traj``'s span: rotation from the bias-corrected gyro (rad/s, body
    frame), held to ``traj``'s rotation over ``smoothing_s`` seconds; position, velocity and biases
    interpolated from ``traj``. Without biases in ``traj`` the gyro is corrected by a constant bias, the
    median difference between the gyro and the ground truth's angular rate (the output then has no biases).

    Raises:
        ConfigError: smoothing_s is not a positive finite number.
        DataError: fewer than two IMU samples fall inside the trajectory, or non-finite gyro samples.
    """
    if not (np.isfinite(smoothing_s) and smoothing_s > 0):
        raise ConfigError(f"attitude smoothing must be a positive number of seconds, got {smoothing_s!r}")
    t_imu_ns = np.asarray(t_imu_ns, dtype=np.int64)
    keep = (t_imu_ns >= traj.t_ns[0]) & (t_imu_ns <= traj.t_ns[-1])
    t = t_imu_ns[keep]
    w = np.asarray(gyro, dtype=np.float64)[keep]
    if t.size < 2:
        raise DataError("fewer than two IMU samples inside the ground truth: no attitude to integrate")
    if not np.all(np.isfinite(w)):
        raise DataError(f"{int((~np.isfinite(w).all(axis=1)).sum())} gyro samples are not finite")
    R_gt = interpolate_rotations(traj.t_ns, traj.R, t)
    dt = np.diff(t).astype(np.float64) * 1e-9
    if traj.bg is not None:
        bg = interpolate_positions(traj.t_ns, traj.bg, t)
    else:   # a constant bias: the median gap between the gyro and the ground truth's own rate
        w_gt = Rotation.from_matrix(np.transpose(R_gt[:-1], (0, 2, 1)) @ R_gt[1:]).as_rotvec() / dt[:, None]
        bg = np.tile(np.median(0.5 * (w[:-1] + w[1:]) - w_gt, axis=0), (t.size, 1))
    steps = Rotation.from_rotvec(0.5 * ((w[:-1] - bg[:-1]) + (w[1:] - bg[1:])) * dt[:, None]).as_matrix()
    R_int = np.empty_like(R_gt)
    R_int[0] = R_gt[0]
    for k in range(steps.shape[0]):
        R_int[k + 1] = R_int[k] @ steps[k]
    # the correction in the world frame: the body rate then stays the gyro's plus R_int^T d delta_s / dt
    delta = Rotation.from_matrix(R_gt @ np.transpose(R_int, (0, 2, 1))).as_rotvec()
    worst = float(np.degrees(np.linalg.norm(delta, axis=1).max()))
    if worst > MAX_DRIFT_DEG:   # also keeps the rotation vectors far from their wrap at 180 deg
        raise DataError(f"the bias-corrected gyro drifts {worst:.0f} deg from the ground truth's attitude "
                        f"(at most {MAX_DRIFT_DEG:g} expected): is the IMU file the ground truth's, on the "
                        "same clock and body frame?")
    rate_hz = 1.0 / float(np.median(dt))
    delta_s = _smooth(delta, smoothing_s * rate_hz)
    R = Rotation.from_matrix(Rotation.from_rotvec(delta_s).as_matrix() @ R_int).as_matrix()  # orthonormal
    p = interpolate_positions(traj.t_ns, traj.p, t)
    v = interpolate_positions(traj.t_ns, traj.v, t) if traj.v is not None else None
    ba = interpolate_positions(traj.t_ns, traj.ba, t) if traj.ba is not None else None
    bg_out = bg if traj.bg is not None else None
    meta = {**(traj.meta or {}), "attitude": f"gyro, held to the ground truth over {smoothing_s:g} s"}
    return PoseTrajectory(t, p, R, v, bg_out, ba, meta=meta)


def _smooth(x: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian smoothing of (N, 3) samples along axis 0 (sigma in samples), the ends extended by point
    reflection so that a linear trend (a constant gyro bias the ground truth does not give) is kept to
    the last sample."""
    pad = min(int(np.ceil(4.0 * sigma)), x.shape[0] - 1)
    if pad < 1:
        return x.copy()
    head = 2.0 * x[0] - x[pad:0:-1]
    tail = 2.0 * x[-1] - x[-2:-pad - 2:-1]
    out = gaussian_filter1d(np.concatenate([head, x, tail]), sigma=sigma, axis=0, mode="nearest")
    return out[pad:pad + x.shape[0]]
