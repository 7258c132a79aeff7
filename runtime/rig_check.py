"""Checks of the rig's gyroscope scale and camera–IMU rotation without a depth model, from the tracked
features and the gyro alone.

With a model, the start-up's DA3 windows name a gyroscope logging deg/s (`runtime.ffinit.gyro_scale`) and a
camera–IMU rotation that is not the one the motion shows (`runtime.ffinit.extrinsics_check`). A run without a
model had neither: its native filter starts at rest with either mistake and diverges once the rig turns,
for reasons that do not name the cause. Here, once a second (`RigCheckConfig.every_s`), the camera's rotation
over the last half second is fitted from the features tracked across it (`runtime.geometry.two_view`) and
set beside the gyro's over the same span (IMU clock: camera stamps + the rig's time offset, raw gyro):
- the gyroscope's scale: the gyro's rotation angle over the span against the camera's, a ratio no extrinsic
  rotation changes, is about 1 with the right units and about 57 with a gyro in deg/s; where the gyro's
  path over the span exceeds `wrap_deg` (150 deg: its net rotation may have wrapped past 180 deg, as a deg/s
  gyro's does) the path stands in for the angle when its ratio lies in the deg/s band
  (`runtime.ffinit.gyro_scale.gyro_camera_ratio`). A median ratio above `FFInitConfig.max_gyro_rate_ratio`
  (15) over the judged spans is a finding;
- the camera–IMU rotation: the spans' rotation pairs are hand–eye fitted (`runtime.ffinit.handeye`, with a
  gyro bias), as the DA3 check does on one window; a fit at least `extrinsics_check_deg` from the rig's
  rotation that explains the spans `extrinsics_check_ratio` times better than the rig's rotation (with its
  own best bias) is a finding, named as the rig's rotation inverted when it is. Unlike the DA3 check, the
  fit's RMS is not bounded: two-view rotations over half a second are noisier than DA3's (fit RMS up to 2
  deg on the aggressive preset), and the ratio alone separates (`davio bench rig-checks-two-view`).
Spans that turn less than `min_camera_deg` are not judged; the check stops after `max_pairs` judged spans or
`max_spans` spans tried (the rig does not change during a run). The last verdict stands: a later span may
clear a finding an earlier median made. Findings are reported (report.json `pipeline.rig_check`, the
console's end-of-run lines), not acted on: the filter still runs on the rig it was given.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from runtime.config_checks import at_least, non_negative, positive
from runtime.ffinit.config import FFInitConfig
from runtime.ffinit.extrinsics_check import rotation_angle_deg
from runtime.ffinit.gyro_scale import gyro_camera_ratio, gyro_unit_hint
from runtime.ffinit.handeye import HandEyeResult, RotationWindow, estimate_handeye, residuals
from runtime.geometry import so3_log
from runtime.geometry.two_view import two_view_rotation
from runtime.imu import Preintegrator
from runtime.msckf.init_common import ImuWindow


@dataclass(frozen=True)
class RigCheckConfig:
    """When and how the model-free rig checks judge (`[rig_check]` of a run's config.toml)."""

    enabled: bool = True
    """Run the checks in a run without the feed-forward start-up (they only report; off saves their two-view
    fits, one a second)."""
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
    max_spans: int = 120
    """Spans tried (judged or not) after which the check stops: a rig that stands or barely turns."""
    wrap_deg: float = 150.0
    """A gyro path longer than this over a span: the path stands in for the net rotation angle."""
    suspect_deg: float = 3.0
    """A hand-eye fit at least this far from the rig's rotation (deg) that explains the spans `suspect_ratio`
    times better than the rig's rotation, without meeting the finding's bounds (`FFInitConfig.
    extrinsics_check_deg` and `extrinsics_check_ratio`: 10 deg and 10x), is a suspicion
    (`extrinsics_suspect`): a rig 3-5 deg off reset the filter again and again with a wrong scale, unnamed.
    `davio bench rig-checks-two-view` (nine recordings, BENCHMARKS.md): with the right rig the fit lay within
    1.44 deg and explained the spans 1.00-1.04x as well as the rig's rotation; with the rig 5 deg off, 4.4-5.5
    deg and 1.25-5.8x, suspected on 7 of 9 at these bounds (not hover, 1.25x, nor the one-axis rotation
    preset)."""
    suspect_ratio: float = 1.3

    def __post_init__(self) -> None:
        s = "rig_check"
        positive(self, s, "span_s", "every_s", "threshold_px", "wrap_deg", "suspect_deg", "suspect_ratio")
        non_negative(self, s, "min_camera_deg")
        at_least(self, s, 15, "min_tracks")
        at_least(self, s, 1, "min_pairs_gyro", "min_pairs_extrinsics", "max_pairs", "max_spans")


@dataclass
class RigCheckReport:
    """What the checks saw: span counts, the gyro/camera rotation ratios (dimensionless), the hand-eye fit
    (degrees) and the findings (one line each, or None)."""

    spans_judged: int = 0
    spans_still: int = 0
    """Spans turning less than `min_camera_deg`."""
    spans_without_tracks: int = 0
    """Spans with too few features tracked across, or no two-view fit."""
    spans_without_imu: int = 0
    """Spans the IMU samples held did not cover (a gap, or a stream far behind the camera's)."""
    spans_without_frame: int = 0
    """Spans with no frame within 0.1 s of their start (a slow or stalled camera)."""
    spans_overwritten: int = 0
    """Spans due while an earlier one still waited for its IMU (the oldest waiting is dropped)."""
    imu_dropped: int = 0
    """IMU samples not kept: non-finite or not after the previous stamp."""
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
    extrinsics_suspect: str | None = None
    """A rotation a few degrees off (RigCheckConfig.suspect_deg), below the finding, or None."""
    done: bool = False
    error: str | None = None
    """Why the check ended early (an exception), or None."""
    ratios: list[float] = field(default_factory=list, repr=False)


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
        # reaches back over a span, the time offset and 3 s of delivery lag
        self._imu = ImuWindow(int((self.cfg.span_s + abs(float(time_offset_s)) + 3.0) * 1e9))
        self._tracks: deque[tuple[int, np.ndarray, np.ndarray]] = deque()
        self._next_ns: int | None = None
        self._pending: deque[tuple] = deque()    # spans due, waiting for the IMU to reach their ends
        self._spans = 0
        self._windows: list[RotationWindow] = []
        self._residuals: list[float] = []

    @property
    def done(self) -> bool:
        return self.report.done

    def on_imu(self, t_ns: int, gyro, accel=(0.0, 0.0, 0.0)) -> None:
        """One IMU sample (IMU clock; rad/s as the driver gives it). Non-finite and out-of-order samples are
        dropped and counted; a span due is judged once the IMU reaches its end."""
        if self.report.done:
            return
        if not self._imu.add(int(t_ns), gyro, accel):
            self.report.imu_dropped += 1
            return
        while self._pending and int(t_ns) >= self._pending[0][1][0] + self.offset_ns:
            a, b = self._pending.popleft()
            try:
                self._judge(a, b)
            except Exception as e:      # a check must never stop the run: it ends, saying why
                self.report.error = f"{type(e).__name__}: {e}"
                self._finish()
                return

    def on_tracks(self, t_ns: int, ids: np.ndarray, xy: np.ndarray) -> None:
        """A frame's features (persistent ids, undistorted normalized coordinates); schedules a span when one
        is due (judged when the IMU reaches its end). Frames without features or out of order are ignored."""
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
        self._spans += 1
        if self._spans > cfg.max_spans:
            self._finish()
            return
        start = t_ns - int(cfg.span_s * 1e9)
        first = min(self._tracks, key=lambda s: abs(s[0] - start))
        if abs(first[0] - start) > int(0.1 * cfg.span_s * 1e9) + 50_000_000:
            self.report.spans_without_frame += 1
            return
        if len(self._pending) >= 4:
            self._pending.popleft()
            self.report.spans_overwritten += 1
        self._pending.append((first, self._tracks[-1]))

    def _finish(self) -> None:
        self.report.done = True
        self._tracks.clear()
        self._pending.clear()
        self._imu.clear()

    def _judge(self, a: tuple, b: tuple) -> None:
        cfg, rep = self.cfg, self.report
        t0, t1 = a[0] + self.offset_ns, b[0] + self.offset_ns
        t, w, _ = self._imu.arrays()
        if len(t) < 2 or t[0] > t0 or t[-1] < t1:
            rep.spans_without_imu += 1
            return
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
        pre = Preintegrator(np.zeros(3), np.zeros(3)).integrate(t, w, np.zeros_like(w), t0, t1)
        rep.spans_judged += 1
        rep.ratios.append(gyro_camera_ratio(t, w, t0, t1, pre.dR, cam_deg, cfg.wrap_deg))
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
            self._finish()

    def _judge_gyro(self) -> None:
        rep, ratio = self.report, self.report.gyro_ratio_median
        if ratio is None or ratio <= self.ffcfg.max_gyro_rate_ratio:
            rep.gyro_scale = None
            return
        rep.gyro_scale = (f"the gyroscope turns {ratio:.1f}x as far as the tracked features see the camera "
                          f"turn (median of {rep.spans_judged} spans of {self.cfg.span_s:g} s)"
                          f"{gyro_unit_hint(ratio)}")

    def _judge_extrinsics(self) -> None:
        rep, ff = self.report, self.ffcfg
        fit = estimate_handeye(self._windows)
        if not isinstance(fit, HandEyeResult):
            return
        rig_rms = _rms_deg(self._windows, self.R_IC, _bias_for(self._windows, self.R_IC))
        off = rotation_angle_deg(self.R_IC, fit.R_IC)
        if np.linalg.norm(fit.bg) > ff.max_gyro_bias_change:     # no calibrated MEMS gyro is that far off
            rep.extrinsics_rotation = rep.extrinsics_suspect = None
            return
        rep.extrinsics_fit_deg, rep.extrinsics_fit_rms_deg = off, fit.rms_deg
        rep.extrinsics_rig_rms_deg = rig_rms
        rep.extrinsics_suspect = None
        if not (off >= ff.extrinsics_check_deg and rig_rms >= ff.extrinsics_check_ratio * fit.rms_deg):
            rep.extrinsics_rotation = None
            if off >= self.cfg.suspect_deg and rig_rms >= self.cfg.suspect_ratio * fit.rms_deg:
                rep.extrinsics_suspect = (
                    f"{rep.spans_judged} spans of tracked features fit a camera-IMU rotation {off:.1f} deg "
                    f"from the rig's, which explains them {rig_rms / max(fit.rms_deg, 1e-9):.1f}x better "
                    f"({fit.rms_deg:.2f} deg RMS, the rig's {rig_rms:.2f})")
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
