"""Is the gyroscope's scale the camera's? DA3's rotation rate against the gyro's, before any solve.

A gyroscope logged in deg/s (or through a wrong full-scale setting) turns 57x (or some other factor) as
fast as the camera does. The bias alignment then asks for an impossible bias step or the rotations stay
inconsistent, and the window is refused for a reason that does not name the cause. Comparing rates names
it: over the window's span, the mean of |omega| (the gyro's path, trapezoidal) against the sum of DA3's
rotation angles between consecutive images (a chord, so at most the path) divided by the span. With the
right units the ratio is about 1 (measured up to 1.17 on the simulator's presets, 3.3 on MH_03's real
IMU: `davio bench rig-checks`); a ratio above `FFInitConfig.max_gyro_rate_ratio` (15) is refused as
`gyro_scale`.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from runtime.ffinit.config import FFInitConfig
from runtime.ffinit.window import ImageObservations, Rejection
from runtime.geometry import so3_log

DEG_PER_RAD = float(np.degrees(1.0))


def rotation_rates(t_cam_ns: Sequence[int], observations: Sequence[ImageObservations], imu_t_ns: np.ndarray,
                   gyro: np.ndarray, time_offset_s: float = 0.0) -> tuple[float, float]:
    """(gyro rate, DA3 rate) in rad/s (the gyro's in its own units) over the window's span: the mean of
    |omega| over the IMU samples within the span (stamps on the IMU clock: t_cam + time_offset_s), and
    DA3's consecutive-image rotation angles summed over the span. NaN when the span holds < 2 samples."""
    t = np.asarray(t_cam_ns, np.int64) + int(round(time_offset_s * 1e9))
    span_s = (int(t[-1]) - int(t[0])) * 1e-9
    imu_t = np.asarray(imu_t_ns, np.int64)
    inside = (imu_t >= t[0]) & (imu_t <= t[-1])
    if inside.sum() < 2 or not span_s > 0:
        return float("nan"), float("nan")
    w = np.linalg.norm(np.asarray(gyro, np.float64)[inside], axis=1)
    ts = (imu_t[inside] - imu_t[inside][0]) * 1e-9
    gyro_rate = float(np.sum(0.5 * (w[1:] + w[:-1]) * np.diff(ts)) / max(ts[-1], 1e-9))
    angle = sum(float(np.linalg.norm(so3_log(a.R_C0Ci.T @ b.R_C0Ci)))
                for a, b in zip(observations, observations[1:], strict=False))
    return gyro_rate, angle / span_s


def check_gyro_scale(t_cam_ns: Sequence[int], observations: Sequence[ImageObservations], imu_t_ns: np.ndarray,
                     gyro: np.ndarray, time_offset_s: float, cfg: FFInitConfig) -> Rejection | None:
    """A `gyro_scale` Rejection when the gyro turns more than `cfg.max_gyro_rate_ratio` times as fast as
    DA3 sees the camera turn (judged only when DA3's rate is at least `cfg.gyro_scale_min_rate`); else None.
    """
    gyro_rate, da3_rate = rotation_rates(t_cam_ns, observations, imu_t_ns, gyro, time_offset_s)
    if not (np.isfinite(gyro_rate) and da3_rate >= cfg.gyro_scale_min_rate):
        return None
    ratio = gyro_rate / da3_rate
    if ratio <= cfg.max_gyro_rate_ratio:
        return None
    return Rejection("gyro_scale", f"the gyroscope turns {ratio:.1f}x as fast as DA3 sees the camera turn "
                                   f"({gyro_rate:.3f} against {da3_rate:.3f} rad/s){gyro_unit_hint(ratio)}")


def gyro_camera_ratio(t_ns: np.ndarray, gyro: np.ndarray, t0_ns: int, t1_ns: int, dR: np.ndarray,
                      camera_deg: float, wrap_deg: float = 150.0) -> float:
    """How many times as far the gyro turns as the camera (`camera_deg`, its rotation angle) from t0 to t1
    (IMU clock). The gyro's angle is that of its net rotation `dR` (its preintegration over the span): the
    net rotation, not the path, compares with a camera's, since an oscillation within the span lengthens
    the path alone. Where the path is longer than `wrap_deg` the net rotation may have wrapped past 180 deg,
    as a gyroscope logging deg/s makes it: the path's ratio is taken then, if it lies in the deg/s band
    (at least 57.3 / 2; a shake on a right gyro lengthens its path a few times, not 30)."""
    from runtime.imu.samples import imu_segment

    w = np.asarray(gyro, np.float64)
    dts, g, _ = imu_segment(np.asarray(t_ns, np.int64), w, np.zeros_like(w), int(t0_ns), int(t1_ns))
    rate = np.linalg.norm(g, axis=1)
    path_deg = float(np.degrees(np.sum(0.5 * (rate[1:] + rate[:-1]) * dts)))
    net = float(np.degrees(np.linalg.norm(so3_log(dR)))) / camera_deg
    path = path_deg / camera_deg
    return path if path_deg > wrap_deg and path >= DEG_PER_RAD / 2 else net


def gyro_unit_hint(ratio: float) -> str:
    """What a gyroscope turning `ratio` times the camera most likely is (a clause for a message)."""
    if DEG_PER_RAD / 2 <= ratio <= DEG_PER_RAD * 2:
        return " - a gyroscope logging deg/s? DAVIO reads rad/s"
    return " - a wrong gyroscope scale or unit"
