"""Checks of the rig's gyroscope scale and camera–IMU rotation without a depth model, from the tracked
features and the gyro alone.

With a model, the start-up's DA3 windows name a gyroscope logging deg/s (`runtime.ffinit.gyro_scale`) and a
camera–IMU rotation that is not the one the motion shows (`runtime.ffinit.extrinsics_check`). A run without a
model had neither: its native filter starts at rest with either mistake and diverges once the rig turns,
for reasons that do not name the cause. Here, once a second (`RigCheckConfig.every_s`), the camera's rotation
over the last half second is fitted from the features tracked across it (`runtime.geometry.two_view`) and
set beside the gyro's over the same span (IMU clock: camera stamps + the rig's time offset, raw gyro):
- the gyroscope's scale: the gyro's path angle over the span against the camera's rotation angle, a ratio no
  extrinsic rotation changes, is about 1 with the right units (the path is at least the chord: more when
  the rig vibrates) and about 57 with a gyro in deg/s; a median ratio above
  `FFInitConfig.max_gyro_rate_ratio` (15) over the judged spans is a finding;
- the camera–IMU rotation: the spans' rotation pairs are hand–eye fitted (`runtime.ffinit.handeye`, with a
  gyro bias), as the DA3 check does on one window; a fit at least `extrinsics_check_deg` from the rig's
  rotation that explains the spans `extrinsics_check_ratio` times better than the rig's rotation (with its
  own best bias) is a finding, named as the rig's rotation inverted when it is.
Spans that turn less than `min_camera_deg` are not judged; the check stops after `max_pairs` judged spans
(the rig does not change during a run). Findings are reported (report.json `pipeline.rig_check`, the
console's end-of-run lines), not acted on: the filter still runs on the rig it was given.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from runtime.ffinit.config import FFInitConfig
from runtime.ffinit.extrinsics_check import rotation_angle_deg
from runtime.ffinit.handeye import HandEyeResult, RotationWindow, estimate_handeye, residuals
from runtime.geometry import so3_log
from runtime.geometry.two_view import two_view_rotation
from runtime.imu import Preintegrator


@dataclass(frozen=True)
class RigCheckConfig:
    """When and how the model-free rig checks judge."""

    span_s: float = 0.5
    """Camera seconds between the two frames of a judged span."""
    every_s: float = 1.0
    """Camera seconds between the starts of judged spans."""
    min_camera_deg: float = 2.0
    """Spans whose camera turns less are not judged (the ratio of small angles is noise)."""
    min_tracks: int = 30
    """Features tracked across a span, at least."""
    threshold_px: float = 1.0
    """The two-view fit's inlier threshold (pixels at the focal length)."""
    min_pairs_gyro: int = 3
    """Judged spans before the gyro's scale is judged."""
    min_pairs_extrinsics: int = 8
    """Judged spans before each hand-eye fit of the camera-IMU rotation (again every as many spans)."""
    max_pairs: int = 40
    """Judged spans after which the check stops."""


@dataclass
class RigCheckReport:
    spans_judged: int = 0
    spans_still: int = 0
    """Spans turning less than `min_camera_deg`."""
    spans_without_tracks: int = 0
    """Spans with too few features tracked across, or no two-view fit."""
    gyro_ratio_median: float | None = None
    gyro_ratio_max: float | None = None
    gyro_scale: str | None = None
    """The finding on the gyroscope's scale, or None."""
    rig_residual_median_deg: float | None = None
    """Median rotation residual of the judged spans with the rig's camera-IMU rotation (no bias)."""
    extrinsics_fit_deg: float | None = None
    """The last hand-eye fit's distance from the rig's rotation (deg)."""
    extrinsics_fit_rms_deg: float | None = None
    extrinsics_rig_rms_deg: float | None = None
    extrinsics_rotation: str | None = None
    """The finding on the camera-IMU rotation, or None."""
    done: bool = False
    error: str | None = None
    """Why the check ended early (an exception), or None."""
    ratios: list = field(default_factory=list, repr=False)


class TwoViewRigCheck:
    """Feeds on the pipeline's IMU samples and feature tracks (see the module docstring).

    Args:
        R_IC: the rig's camera-to-IMU rotation (3, 3).
        time_offset_s: the rig's camera-IMU offset (t_imu = t_cam + offset).
        focal_px: the camera's focal length (pixels).
    """

    def __init__(self, R_IC: np.ndarray, time_offset_s: float, focal_px: float,
                 cfg: RigCheckConfig | None = None, ffcfg: FFInitConfig | None = None) -> None:
        self.R_IC = np.asarray(R_IC, np.float64)
        self.offset_ns = int(round(float(time_offset_s) * 1e9))
        self.focal_px = float(focal_px)
        self.cfg = cfg or RigCheckConfig()
        self.ffcfg = ffcfg or FFInitConfig()
        self.report = RigCheckReport()
        self._imu_t: deque[int] = deque()
        self._imu_w: deque[tuple[float, float, float]] = deque()
        self._tracks: deque[tuple[int, np.ndarray, np.ndarray]] = deque()
        self._next_ns: int | None = None
        self._pending: tuple | None = None     # a span due, waiting for the IMU to reach its end
        self._windows: list[RotationWindow] = []
        self._residuals: list[float] = []

    @property
    def done(self) -> bool:
        return self.report.done

    def on_imu(self, t_ns: int, gyro) -> None:
        """One IMU sample (IMU clock, rad/s as the driver gives it)."""
        if self.report.done:
            return
        self._imu_t.append(int(t_ns))
        self._imu_w.append((float(gyro[0]), float(gyro[1]), float(gyro[2])))
        horizon = int(t_ns) - int(3e9)
        while self._imu_t and self._imu_t[0] < horizon:
            self._imu_t.popleft()
            self._imu_w.popleft()
        if self._pending is not None and int(t_ns) >= self._pending[1][0] + self.offset_ns:
            pending, self._pending = self._pending, None
            try:
                self._judge(*pending)
            except Exception as e:      # a check must never stop the run: it ends, saying why
                self.report.error = f"{type(e).__name__}: {e}"
                self.report.done = True

    def on_tracks(self, t_ns: int, ids: np.ndarray, xy: np.ndarray) -> None:
        """A frame's features (persistent ids, undistorted normalized coordinates); judges a span when due."""
        if self.report.done or not len(ids) or (self._tracks and int(t_ns) <= self._tracks[-1][0]):
            return
        cfg = self.cfg
        t_ns = int(t_ns)
        self._tracks.append((t_ns, np.asarray(ids), np.asarray(xy, np.float64)))
        while t_ns - self._tracks[0][0] > int((cfg.span_s + 0.5) * 1e9):
            self._tracks.popleft()
        if self._next_ns is None:
            self._next_ns = t_ns + int(cfg.span_s * 1e9)
        if t_ns < self._next_ns:
            return
        self._next_ns = t_ns + int(cfg.every_s * 1e9)
        start = t_ns - int(cfg.span_s * 1e9)
        first = min(self._tracks, key=lambda s: abs(s[0] - start))
        if abs(first[0] - start) > int(0.1 * cfg.span_s * 1e9) + 50_000_000:
            return
        self._pending = (first, self._tracks[-1])     # judged once the IMU covers its end

    def _judge(self, a: tuple, b: tuple) -> None:
        cfg, rep = self.cfg, self.report
        _, ia, ib = np.intersect1d(a[1], b[1], assume_unique=True, return_indices=True)
        fit = None
        if len(ia) >= cfg.min_tracks:
            fit = two_view_rotation(a[2][ia], b[2][ib], cfg.threshold_px / self.focal_px,
                                    min_inliers=cfg.min_tracks // 2)
        if fit is None:
            rep.spans_without_tracks += 1
            return
        R_C0C1 = fit.R_BA.T
        cam_deg = float(np.degrees(np.linalg.norm(so3_log(R_C0C1))))
        if cam_deg < cfg.min_camera_deg:
            rep.spans_still += 1
            return
        t0, t1 = a[0] + self.offset_ns, b[0] + self.offset_ns
        t = np.fromiter(self._imu_t, np.int64, len(self._imu_t))
        if len(t) < 2 or t[0] > t0 or t[-1] < t1:
            rep.spans_without_tracks += 1
            return
        w = np.array(self._imu_w)
        pre = Preintegrator(np.zeros(3), np.zeros(3)).integrate(t, w, np.zeros_like(w), t0, t1)
        inside = (t >= t0) & (t <= t1)
        rate = np.linalg.norm(w[inside], axis=1)
        dt = np.diff(t[inside]) * 1e-9
        # the gyro's path (not its net rotation, which wraps past 180 deg at 57x): at least the chord
        gyro_deg = float(np.degrees(np.sum(0.5 * (rate[1:] + rate[:-1]) * dt) * (t1 - t0) * 1e-9
                                    / max(float(np.sum(dt)), 1e-9)))
        rep.spans_judged += 1
        rep.ratios.append(gyro_deg / cam_deg)
        rep.gyro_ratio_median = float(np.median(rep.ratios))
        rep.gyro_ratio_max = float(np.max(rep.ratios))
        window = RotationWindow(R_C0C1[None], pre.dR[None], pre.J_R_bg[None], np.zeros(3))
        self._windows.append(window)
        self._residuals.append(float(np.degrees(np.linalg.norm(residuals([window], self.R_IC, np.zeros(3))))))
        rep.rig_residual_median_deg = float(np.median(self._residuals))
        if rep.spans_judged >= cfg.min_pairs_gyro:
            self._judge_gyro()
        if (rep.gyro_scale is None and rep.spans_judged >= cfg.min_pairs_extrinsics
                and rep.spans_judged % cfg.min_pairs_extrinsics == 0):
            self._judge_extrinsics()
        if rep.spans_judged >= cfg.max_pairs:
            rep.done = True
            self._tracks.clear()
            self._imu_t.clear()
            self._imu_w.clear()

    def _judge_gyro(self) -> None:
        rep, ratio = self.report, self.report.gyro_ratio_median
        if ratio is None or ratio <= self.ffcfg.max_gyro_rate_ratio:
            rep.gyro_scale = None
            return
        deg = float(np.degrees(1.0))
        hint = (" - a gyroscope logging deg/s? DAVIO reads rad/s" if deg / 2 <= ratio <= deg * 2
                else " - a wrong gyroscope scale or unit")
        rep.gyro_scale = (f"the gyroscope turns {ratio:.1f}x as far as the tracked features see the camera "
                          f"turn (median of {rep.spans_judged} spans of {self.cfg.span_s:g} s){hint}")

    def _judge_extrinsics(self) -> None:
        rep, ff = self.report, self.ffcfg
        fit = estimate_handeye(self._windows)
        if not isinstance(fit, HandEyeResult):
            return
        rig_rms = _rms_deg(self._windows, self.R_IC, _bias_for(self._windows, self.R_IC))
        off = rotation_angle_deg(self.R_IC, fit.R_IC)
        rep.extrinsics_fit_deg, rep.extrinsics_fit_rms_deg = off, fit.rms_deg
        rep.extrinsics_rig_rms_deg = rig_rms
        if not (off >= ff.extrinsics_check_deg and rig_rms >= ff.extrinsics_check_ratio * fit.rms_deg):
            rep.extrinsics_rotation = None
            return
        inverted = rotation_angle_deg(self.R_IC.T, fit.R_IC) <= ff.extrinsics_check_deg / 2
        rep.extrinsics_rotation = (
            f"the rig's camera-IMU rotation is {off:.1f} deg from the one {rep.spans_judged} spans of "
            f"tracked features fit ({fit.rms_deg:.2f} deg RMS, the rig's {rig_rms:.2f})"
            + (": the rig's rotation inverted - T_cam_imu given as T_imu_cam, or the reverse?" if inverted
               else ""))


def _bias_for(windows: list[RotationWindow], R_IC: np.ndarray, iterations: int = 3) -> np.ndarray:
    """The gyro bias (rad/s) that best fits `windows` with the camera-IMU rotation held at R_IC (a few
    Gauss-Newton steps of the hand-eye residual in the bias alone, small-residual Jacobian -J_R_bg)."""
    bg = np.zeros(3)
    J = np.concatenate([w.J_R_bg for w in windows]).reshape(-1, 3)
    for _ in range(iterations):
        r = residuals(windows, R_IC, bg).ravel()
        bg = bg + np.linalg.lstsq(J, r, rcond=None)[0]
    return bg


def _rms_deg(windows: list[RotationWindow], R_IC: np.ndarray, bg: np.ndarray) -> float:
    r = residuals(windows, R_IC, bg)
    return float(np.degrees(np.sqrt(np.mean(np.sum(r ** 2, axis=1)))))
