"""Is the camera–IMU time offset in use (the rig's, or one the start-up adopted) the one the motion shows?
Asked of a window the DA3–gyro alignment refused (`gyro_bias_step`, `rotation_inconsistent`) when the
rotation check found nothing.

A camera stamped late or early against the IMU (a UVC camera stamped on the host after readout and
transfer, a serial IMU's own latency: tens of ms are common, and Kalibr's `timeshift_cam_imu` is what
the rig file lacks) shifts every image's gyro interval. The rotations then disagree wherever the rate
changes, by about the rate change times the shift, and from about 30 ms on every window is refused for a
reason that does not name the cause (measured on the hand-held preset: 14 of 28 windows at 10 ms, all at
30 ms). A scan of the shift tells the two apart: the gyro is integrated once over the window and a margin,
and for each shift on a grid the consecutive-image rotations are compared with DA3's after the best gyro
bias for that shift (least squares, first order). Only the image pairs the IMU covers at every shift are
compared: live, the IMU handed to a window ends just past its newest image, so the last pair is left out
and three pairs of a five-image window are scanned. When the best shift is at least
`FFInitConfig.time_offset_check_s` from zero, fits within `max_rotation_residual_deg` (the consistency gate
would then pass) with a plausible bias step, and `time_offset_check_ratio` times better than the offset in
use does, the window is solved again at that offset (every gate as before). An accepted state carries the
offset to the filter it starts; a refusal a longer span could cure keeps its reason and re-solve seed;
any other refusal becomes `time_offset`, saying how far and which way. Either way the finding travels with
the result, and the start-up adopts it (`ffinit.correct_time_offset`; without it every such window is only
refused as `time_offset`).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from runtime.ffinit.config import FFInitConfig
from runtime.ffinit.window import ImageObservations


@dataclass
class OffsetScan:
    """RMS rotation residual (deg) of the consecutive-image rotations against each trial shift (s, added to
    the time offset in use), each with its own least-squares gyro-bias step (rad/s)."""

    shifts_s: np.ndarray
    rms_deg: np.ndarray
    bias_step: np.ndarray

    @property
    def best(self) -> int:
        """Index of the shift with the smallest residual."""
        return int(np.nanargmin(self.rms_deg))

    def refined_shift(self, b: int) -> float:
        """The shift of the parabola through the mean squared residuals at grid points b-1, b, b+1 (the grid
        point itself at the range's edge or where the three are not convex)."""
        if not 0 < b < len(self.shifts_s) - 1:
            return float(self.shifts_s[b])
        m, c, p = (float(x) ** 2 for x in self.rms_deg[b - 1:b + 2])
        curvature = m - 2 * c + p
        if not curvature > 0:
            return float(self.shifts_s[b])
        step = float(self.shifts_s[b + 1] - self.shifts_s[b])
        return float(self.shifts_s[b]) + step * float(np.clip(0.5 * (m - p) / curvature, -0.5, 0.5))

    def rms_at(self, shift_s: float) -> float:
        """The residual at the grid shift nearest `shift_s`."""
        return float(self.rms_deg[int(np.argmin(np.abs(self.shifts_s - shift_s)))])


def _cumulative_rotations(t_s: np.ndarray, gyro: np.ndarray) -> np.ndarray:
    """(n, 3, 3) R_I(t_0) -> R_I(t_k): the gyro integrated sample to sample (midpoint rates)."""
    from scipy.spatial.transform import Rotation

    steps = Rotation.from_rotvec(0.5 * (gyro[1:] + gyro[:-1]) * np.diff(t_s)[:, None]).as_matrix()
    out = np.empty((len(t_s), 3, 3))
    out[0] = np.eye(3)
    for k, step in enumerate(steps):
        out[k + 1] = out[k] @ step
    return out


def imu_lead_s(cfg: FFInitConfig) -> float:
    """IMU (s) a start-up window's solve needs before its first image: the scan's range plus 20 ms."""
    return cfg.time_offset_check_range_s + 0.02


MIN_PAIRS = 3
"""Consecutive-image pairs the scan needs (each gives three residuals; the bias takes three)."""


def scan_time_offset(t_cam_ns: Sequence[int], observations: Sequence[ImageObservations], R_IC: np.ndarray,
                     imu_t_ns: np.ndarray, gyro: np.ndarray, time_offset_s: float,
                     shifts_s: np.ndarray) -> OffsetScan | None:
    """The residual of every trial shift (module docstring), or None when fewer than `MIN_PAIRS`
    consecutive-image pairs have IMU samples at every shift. Only such pairs are compared: live, the IMU
    ends near the newest image, so a shift towards later IMU times leaves the last pair out."""
    from scipy.spatial.transform import Rotation, Slerp

    shifts_s = np.asarray(shifts_s, np.float64)
    imu_t = np.asarray(imu_t_ns, np.int64)
    t_imu = np.asarray(t_cam_ns, np.int64) + int(round(time_offset_s * 1e9))
    if len(t_imu) < MIN_PAIRS + 1 or len(imu_t) < 2:
        return None
    lo_ns, hi_ns = int(round(shifts_s.min() * 1e9)), int(round(shifts_s.max() * 1e9))
    pairs = np.flatnonzero((t_imu[:-1] + lo_ns >= imu_t[0]) & (t_imu[1:] + hi_ns <= imu_t[-1]))
    if len(pairs) < MIN_PAIRS:
        return None
    used = np.union1d(pairs, pairs + 1)                       # images of the usable pairs
    base = int(t_imu[used[0]])
    first = max(int(np.searchsorted(imu_t, base + lo_ns, "right")) - 1, 0)
    last = min(int(np.searchsorted(imu_t, int(t_imu[used[-1]]) + hi_ns, "left")), len(imu_t) - 1)
    t_s = (imu_t[first:last + 1] - base) * 1e-9
    R_cum = _cumulative_rotations(t_s, np.asarray(gyro, np.float64)[first:last + 1])
    query = ((t_imu[used] - base) * 1e-9)[None, :] + shifts_s[:, None]        # (S, images) on the IMU clock
    query = np.clip(query, t_s[0], t_s[-1])     # a sample exactly at an end: float rounding, not a gap
    R_q = Slerp(t_s, Rotation.from_matrix(R_cum))(query.ravel()).as_matrix().reshape(len(shifts_s), -1, 3, 3)
    a, b = np.searchsorted(used, pairs), np.searchsorted(used, pairs + 1)
    R_pre = np.einsum("snji,snjk->snik", R_q[:, a], R_q[:, b])                 # the pairs' IMU increments
    R_IC = np.asarray(R_IC, np.float64)
    R_da3 = np.array([R_IC @ observations[i].R_C0Ci.T @ observations[i + 1].R_C0Ci @ R_IC.T for i in pairs])
    E = np.einsum("snji,njk->snik", R_pre, R_da3)                              # R_pre^T R_da3
    r = Rotation.from_matrix(E.reshape(-1, 3, 3)).as_rotvec().reshape(len(shifts_s), -1, 3)
    # a bias step dbg turns each increment by about -dt_i dbg: r_i(dbg) = r_i + dt_i dbg
    dt = (t_imu[pairs + 1] - t_imu[pairs]) * 1e-9
    dbg = -np.einsum("i,sik->sk", dt, r) / float(dt @ dt)
    res = r + dt[None, :, None] * dbg[:, None, :]
    rms = np.degrees(np.sqrt(np.mean(np.sum(res ** 2, axis=2), axis=1)))
    return OffsetScan(shifts_s, rms, np.linalg.norm(dbg, axis=1))


@dataclass
class OffsetFit:
    """A camera-IMU time offset the window's rotations fit far better than the one in use."""

    shift_s: float
    """Added to the offset in use (t_imu = t_cam + offset), s."""
    rms_deg: float
    """RMS rotation residual there, degrees."""
    in_use_rms_deg: float
    """RMS rotation residual at the offset in use, degrees."""

    def describe(self, offset_s: float) -> str:
        """One line for reports: the shift from `offset_s` (the offset in use, s), both fits, and which way
        the camera's stamps run (a negative shift: later than the offset in use says)."""
        ms = self.shift_s * 1e3
        return (f"the window's rotations fit a camera-IMU time offset {ms:+.0f} ms from the one in use "
                f"({offset_s * 1e3:+.1f} ms, t_imu = t_cam + offset; {self.rms_deg:.3f} deg RMS there, "
                f"{self.in_use_rms_deg:.2f} at the one in use): the camera's stamps run {abs(ms):.0f} ms "
                f"{'early' if ms > 0 else 'late'} against the IMU's")


def fit_time_offset(t_cam_ns: Sequence[int], observations: Sequence[ImageObservations], R_IC: np.ndarray,
                    imu_t_ns: np.ndarray, gyro: np.ndarray, time_offset_s: float,
                    cfg: FFInitConfig) -> OffsetFit | None:
    """The shift the window's rotations fit when it is far from the offset in use and fits far better
    (module docstring), else None: the best shift is near zero, at the edge of the scanned range, fits
    no better than the consistency gate allows, needs an implausible bias step, or the offset in use fits
    nearly as well (the rotation rate hardly changes in the window, so the shift is not determined)."""
    step = cfg.time_offset_check_step_s
    n = int(np.floor(cfg.time_offset_check_range_s / step + 1e-9))
    scan = scan_time_offset(t_cam_ns, observations, R_IC, imu_t_ns, gyro, time_offset_s,
                            np.arange(-n, n + 1) * step)
    if scan is None or not np.isfinite(scan.rms_deg).all():
        return None
    b = scan.best
    fit = OffsetFit(scan.refined_shift(b), float(scan.rms_deg[b]), scan.rms_at(0.0))
    if not (abs(fit.shift_s) >= cfg.time_offset_check_s and fit.rms_deg <= cfg.max_rotation_residual_deg
            and fit.in_use_rms_deg >= cfg.time_offset_check_ratio * fit.rms_deg
            and scan.bias_step[b] <= cfg.max_gyro_bias_change and 0 < b < len(scan.shifts_s) - 1):
        return None
    return fit
