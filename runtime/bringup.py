"""Calibration-withheld bring-up (paper Sec. IV-D): while the camera–IMU rotation is unknown, the camera's
relative rotations over early windows are aligned with preintegrated IMU rotations (hand–eye) to estimate
R_IC and the gyro bias; the estimate is validated on a later window. The lever arm and the time
offset then start at zero and the filter refines all three online.

The camera's rotations come from a DA3 start-up call on each window (the paper's way) or, without a depth
model, from the tracked features: the two-view rotation between the window's first image and each later
one (`runtime.geometry.two_view`: an essential matrix, or a pure rotation where the parallax is too small).
"""
from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from models.depth_model import DepthModel, checked_prediction
from runtime.config_checks import at_least, non_negative, positive
from runtime.events import Frame, ImuSample
from runtime.ffinit.gyro_scale import gyro_camera_ratio, gyro_unit_hint
from runtime.ffinit.handeye import HandEyeResult, RotationWindow, estimate_handeye, validate_handeye
from runtime.ffinit.window import Rejection
from runtime.geometry.two_view import two_view_rotation
from runtime.imu import Preintegrator


@dataclass
class BringUpConfig:
    """Hand–eye bring-up parameters (`[bringup]` of a run's config.toml). A failed estimate or validation
    drops the oldest window and waits for the next one: the bring-up keeps trying until the recording ends
    (or the live run is stopped), and the report counts each attempt and rejection."""

    fit_windows: int = 8
    """Early windows the rotation is estimated from."""
    window_images: int = 5
    window_spacing_s: float = 0.2
    """Each window: five images spaced 0.2 s (as the start-up window)."""
    window_gap_s: float = 0.5
    """At least this much sensor time between the starts of consecutive windows."""
    min_rotation_deg: float = 5.0
    """Windows rotating less than this (gyro, end to end) carry no hand-eye information: skipped."""
    two_view_min_tracks: int = 30
    """Without a depth model: features tracked from a window's first image to each later one, at least."""
    two_view_threshold_px: float = 1.0
    """Without a depth model: the two-view fits' inlier threshold (pixels at the focal length)."""
    max_gyro_ratio: float = 15.0
    """A window whose gyro turns more than this many times as far as its camera (over the window) is
    refused as `gyro_scale` (a gyroscope logging deg/s turns 57 times as far; as
    `ffinit.max_gyro_rate_ratio`)."""
    max_fit_rms_deg: float = 30.0
    """A hand-eye fit leaving more RMS than this (deg) is refused as `handeye_poor_fit`: no rotation fits
    the windows (without the bound a deg/s gyro's 99 deg fit passed its validation at 126 deg). Accepted
    fits measured 0.1-3.5 deg (BENCHMARKS.md "Calibration-withheld bring-up without a depth model"); a
    review's shaken rig with an 80 ms time offset fitted at 11 deg and still started within 2.4 deg, so
    the bound is set well above that (a fit's RMS is unweighted, its solve Huber-weighted)."""

    def __post_init__(self) -> None:
        s = "bringup"
        at_least(self, s, 1, "fit_windows")
        at_least(self, s, 3, "window_images")
        at_least(self, s, 15, "two_view_min_tracks")
        positive(self, s, "window_spacing_s", "two_view_threshold_px", "max_gyro_ratio", "max_fit_rms_deg")
        non_negative(self, s, "window_gap_s", "min_rotation_deg")


@dataclass
class BringUpReport:
    rotation_source: str = "model"
    """Where the camera's rotations came from: "model" (DA3 calls) or "tracks" (two-view fits)."""
    two_view_models: dict = field(default_factory=dict)
    """Without a model: the camera rotations of every window received (also those a failed estimate later
    dropped) by how they were found: two-view fits from the window's first image ("essential",
    "rotation"), or "chained" frame to frame."""
    windows_used: int = 0
    windows_skipped_static: int = 0
    min_rotation_deg: float = 5.0
    """The bound below which a window was skipped as static (`BringUpConfig.min_rotation_deg`)."""
    attempts: int = 0
    rejections: dict = field(default_factory=dict)
    rejection_first: dict = field(default_factory=dict)
    """The first message of each window rejection reason that has one."""
    R_IC: list | None = None
    bg: list | None = None
    fit_rms_deg: float | None = None
    validation_rms_deg: float | None = None
    done_t_ns: int | None = None


class HandEyeBringUp:
    """Collects windows, estimates their camera rotations in the model worker (a DA3 call, or two-view fits
    of the tracked features when `model` is None), estimates R_IC.

    Args:
        model: the depth model, or None to take the rotations from the features fed to `on_tracks`.
        cfg: bring-up settings.
        focal_px: the camera's focal length (pixels): the two-view threshold's unit (needed without a
            model).
    """

    def __init__(self, model: DepthModel | None, cfg: BringUpConfig | None = None,
                 focal_px: float | None = None) -> None:
        if model is None and not (focal_px is not None and focal_px > 0):
            raise ValueError("a bring-up without a depth model needs the camera's focal length (pixels)")
        self.model = model
        self.cfg = cfg or BringUpConfig()
        self.focal_px = focal_px
        self.frames: deque[Frame] = deque()
        self.tracks: deque[tuple[int, np.ndarray, np.ndarray]] = deque()
        # held frames or track sets reach back this far (ns): a window and its gap, at any frame rate
        self._hold_ns = int(((self.cfg.window_images - 1) * self.cfg.window_spacing_s + 1.0) * 1e9)
        self.imu_t: deque[int] = deque()
        self.imu_w: deque[np.ndarray] = deque()
        self.imu_a: deque[np.ndarray] = deque()
        self.windows: list[RotationWindow] = []
        self.result: HandEyeResult | None = None
        self.report = BringUpReport(rotation_source="model" if model is not None else "tracks",
                                    min_rotation_deg=self.cfg.min_rotation_deg)
        self._last_start: int | None = None

    @property
    def done(self) -> bool:
        return self.result is not None

    def on_imu(self, s: ImuSample) -> None:
        self.imu_t.append(int(s.t_ns))
        self.imu_w.append(np.asarray(s.gyro, float))
        self.imu_a.append(np.asarray(s.accel, float))
        while self.imu_t and self.imu_t[0] < self.imu_t[-1] - 20_000_000_000:
            self.imu_t.popleft()
            self.imu_w.popleft()
            self.imu_a.popleft()

    def on_frame(self, f: Frame) -> None:
        """A camera frame (kept for the model's calls; not needed without a model)."""
        if self.model is not None:
            self.frames.append(f)
            while int(f.t_ns) - int(self.frames[0].t_ns) > self._hold_ns:
                self.frames.popleft()

    def on_tracks(self, t_ns: int, ids: np.ndarray, xy: np.ndarray) -> None:
        """The tracker's features at a frame: persistent ids (M,) and undistorted normalized coordinates
        (M, 2) (kept for the two-view fits; not needed with a model). A frame the tracker gave no features
        (dark, frozen, out of order: its tracks resume at the next good frame) is not held."""
        if self.model is None and len(ids) and (not self.tracks or int(t_ns) > self.tracks[-1][0]):
            self.tracks.append((int(t_ns), np.asarray(ids), np.asarray(xy, np.float64)))
            while int(t_ns) - self.tracks[0][0] > self._hold_ns:
                self.tracks.popleft()

    def _window(self) -> tuple[list, list] | None:
        """(the newest window's frames (with a model) or track sets (without), every held one from its first
        to its last), or None when none is due."""
        held = self.frames if self.model is not None else self.tracks
        if not held:
            return None
        t = np.array([_stamp(x) for x in held], np.int64)
        last = int(t[-1])
        n = self.cfg.window_images
        start = last - int(round((n - 1) * self.cfg.window_spacing_s * 1e9))
        if self._last_start is not None and start - self._last_start < self.cfg.window_gap_s * 1e9:
            return None
        picked, first = [], None
        for k in range(n):
            ideal = start + int(round(k * self.cfg.window_spacing_s * 1e9))
            j = int(np.argmin(np.abs(t - ideal)))
            if abs(int(t[j]) - ideal) > 30_000_000:
                return None
            picked.append(held[j])
            first = j if first is None else first
        if not self.imu_t or self.imu_t[0] > _stamp(picked[0]) or self.imu_t[-1] < _stamp(picked[-1]):
            return None
        self._last_start = start
        return picked, list(held)[first:j + 1]

    def next_job(self) -> Callable[[], Any] | None:
        """A closure for the model worker: the newest window's camera rotations (DA3, or two-view fits of
        its tracks) -> RotationWindow; None when it barely rotates; a Rejection when its tracks cannot
        tell. Without a model the job calls none (its `model_call` is False)."""
        if self.done:
            return None
        due = self._window()
        if due is None:
            return None
        picked, span = due
        t = np.fromiter(self.imu_t, np.int64, len(self.imu_t))
        w, a = np.array(self.imu_w), np.array(self.imu_a)
        model, cfg, focal_px = self.model, self.cfg, self.focal_px

        def job() -> RotationWindow | Rejection | None:
            pre = Preintegrator(np.zeros(3), np.zeros(3))
            stamps = [_stamp(x) for x in picked]
            ints = [pre.integrate(t, w, a, stamps[0], s) for s in stamps[1:]]
            if np.degrees(np.linalg.norm(_log(ints[-1].dR))) < cfg.min_rotation_deg:
                return None
            models: tuple[str, ...] = ()
            if model is not None:
                pred = checked_prediction(model.predict(list(picked)), picked)
                R_C0Ci = np.array([pred.T_CW[k][:3, :3].T for k in range(1, len(picked))])
            else:
                fits = _two_view_rotations(span, stamps, cfg, float(focal_px))
                if isinstance(fits, Rejection):
                    return fits
                R_C0Ci, models = fits
            scale = _gyro_scale(t, w, stamps[0], stamps[-1], ints[-1].dR, R_C0Ci[-1], cfg)
            if scale is not None:
                return scale
            return RotationWindow(R_C0Ci, np.array([p.dR for p in ints]), np.array([p.J_R_bg for p in ints]),
                                  np.zeros(3), two_view_models=models)

        if model is None:
            job.model_call = False   # type: ignore[attr-defined]  (a solve: FastClock's solve latency)
        return job

    def on_result(self, rw: RotationWindow | Rejection | None, t_ns: int) -> bool:
        """Add a finished window; returns True once R_IC is estimated and validated."""
        if rw is None:
            self.report.windows_skipped_static += 1
            return False
        if isinstance(rw, Rejection):
            self.report.rejections[rw.reason] = self.report.rejections.get(rw.reason, 0) + 1
            if rw.detail:
                self.report.rejection_first.setdefault(rw.reason, rw.detail)
            return False
        for m in rw.two_view_models:
            self.report.two_view_models[m] = self.report.two_view_models.get(m, 0) + 1
        self.windows.append(rw)
        self.report.windows_used = len(self.windows)
        if len(self.windows) < self.cfg.fit_windows + 1:
            return False
        fit, val = self.windows[:-1], self.windows[-1]
        self.report.attempts += 1
        res = estimate_handeye(fit)
        if isinstance(res, Rejection):
            self._reject(res.reason)
            return False
        ok, rms = validate_handeye(res, val)
        self.report.fit_rms_deg, self.report.validation_rms_deg = res.rms_deg, rms
        if res.rms_deg > self.cfg.max_fit_rms_deg:
            self._reject("handeye_poor_fit")
            return False
        if not ok:
            self._reject("handeye_validation_failed")
            return False
        self.result = res
        self.report.R_IC, self.report.bg = res.R_IC.tolist(), res.bg.tolist()
        self.report.done_t_ns = int(t_ns)
        return True

    def _reject(self, reason: str) -> None:
        self.report.rejections[reason] = self.report.rejections.get(reason, 0) + 1
        self.windows = self.windows[1:]  # slide: drop the oldest window, keep collecting


def _gyro_scale(t: np.ndarray, w: np.ndarray, t0_ns: int, t1_ns: int, dR: np.ndarray, R_C0C1: np.ndarray,
                cfg: BringUpConfig) -> Rejection | None:
    """A `gyro_scale` Rejection when the gyro turns more than `cfg.max_gyro_ratio` times as far as the camera
    over a window (judged when the camera turns at least 2 deg; camera stamps, the offset being unknown)."""
    cam_deg = float(np.degrees(np.linalg.norm(_log(R_C0C1))))
    if cam_deg < 2.0:
        return None
    ratio = gyro_camera_ratio(t, w, t0_ns, t1_ns, dR, cam_deg)
    if ratio <= cfg.max_gyro_ratio:
        return None
    return Rejection("gyro_scale", f"the gyroscope turns {ratio:.1f}x as far as the camera over a window"
                                   f"{gyro_unit_hint(ratio)}")


def _stamp(x: Any) -> int:
    """A held frame's or track set's time (ns)."""
    return int(x.t_ns) if isinstance(x, Frame) else int(x[0])


def _two_view_rotations(span: list, stamps: list[int], cfg: BringUpConfig,
                        focal_px: float) -> tuple[np.ndarray, tuple[str, ...]] | Rejection:
    """((N-1, 3, 3) R_C0Ci, how each was found) of a window's images at `stamps` (ns), from the track sets
    [(t_ns, ids, xy)] of every frame of its `span` (the first image's to the last's). Each from the features
    tracked from image 0 to image i (the two-view model: "essential" or "rotation") or, when that fit fails
    (most often too few of those features last: a fast turn takes them out of view), "chained": from the
    latest frame already placed, one frame at a time. A Rejection (`two_view_too_few_tracks`,
    `two_view_failed`) when a frame cannot be placed."""
    times = [int(x[0]) for x in span]
    R_0k: dict[int, np.ndarray] = {0: np.eye(3)}      # span index -> R_C0Ck
    out, how = [], []
    for t in stamps[1:]:
        k = times.index(int(t))
        fit, n_common = _pair_rotation(span[0], span[k], cfg, focal_px)
        if fit is not None:
            R_0k[k] = fit.R_BA.T     # R_BA = R_CkC0
            how.append(fit.model)
        else:
            q = max(j for j in R_0k if j < k)
            for j in range(q + 1, k + 1):
                step, n_step = _pair_rotation(span[j - 1], span[j], cfg, focal_px)
                if step is None:
                    if n_step < cfg.two_view_min_tracks:
                        return Rejection("two_view_too_few_tracks",
                                         f"{n_step} features tracked into a frame of the "
                                         f"window (< {cfg.two_view_min_tracks})")
                    return Rejection("two_view_failed",
                                     f"no rotation explains {cfg.two_view_min_tracks // 2} of the features "
                                     "tracked into a frame of the window")
                R_0k[j] = R_0k[j - 1] @ step.R_BA.T
            how.append("chained")
        out.append(R_0k[k])
    return np.array(out), tuple(how)


def _pair_rotation(a: tuple, b: tuple, cfg: BringUpConfig, focal_px: float) -> tuple[Any, int]:
    """(TwoViewRotation or None, features common to the two track sets)."""
    _, ids_a, xy_a = a
    _, ids_b, xy_b = b
    _, ia, ib = np.intersect1d(ids_a, ids_b, assume_unique=True, return_indices=True)
    if len(ia) < cfg.two_view_min_tracks:
        return None, len(ia)
    return two_view_rotation(xy_a[ia], xy_b[ib], cfg.two_view_threshold_px / focal_px,
                             min_inliers=cfg.two_view_min_tracks // 2), len(ia)


def _log(R: np.ndarray) -> np.ndarray:
    from runtime.geometry import so3_log

    return so3_log(R)


def gyro_blamed(report: dict) -> str | None:
    """The first `gyro_scale` message of a bring-up report (a dict) that never completed and refused at
    least three windows, and most of those it saw, for the gyroscope's scale; else None."""
    if not report or report.get("R_IC"):
        return None
    rejections = report.get("rejections") or {}
    n_gyro = int(rejections.get("gyro_scale", 0))
    seen = int(report.get("windows_used", 0)) + sum(int(v) for v in rejections.values())
    if n_gyro < 3 or n_gyro * 2 < seen:
        return None
    return (report.get("rejection_first") or {}).get("gyro_scale")
