"""Calibration-withheld bring-up (paper Sec. IV-D): while the camera–IMU rotation is unknown, DA3
start-up calls on early windows are aligned with preintegrated IMU rotations (hand–eye) to estimate
R_IC and the gyro bias; the estimate is validated on a later window. The lever arm and the time
offset then start at zero and the filter refines all three online."""
from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from models.depth_model import DepthModel
from runtime.config_checks import at_least, non_negative, positive
from runtime.events import Frame, ImuSample
from runtime.ffinit.handeye import HandEyeResult, RotationWindow, estimate_handeye, validate_handeye
from runtime.ffinit.window import Rejection
from runtime.imu import Preintegrator


@dataclass
class BringUpConfig:
    """Hand–eye bring-up parameters."""

    fit_windows: int = 8
    """Early windows the rotation is estimated from."""
    window_images: int = 5
    window_spacing_s: float = 0.2
    """Each window: five images spaced 0.2 s (as the start-up window)."""
    window_gap_s: float = 0.5
    """At least this much sensor time between the starts of consecutive windows."""
    min_rotation_deg: float = 5.0
    """Windows rotating less than this (gyro, end to end) carry no hand-eye information: skipped."""
    max_attempts: int = 3
    """Estimate + validation attempts before giving up (each failure drops the oldest windows)."""

    def __post_init__(self) -> None:
        s = "bringup"
        at_least(self, s, 1, "fit_windows", "max_attempts")
        at_least(self, s, 3, "window_images")
        positive(self, s, "window_spacing_s")
        non_negative(self, s, "window_gap_s", "min_rotation_deg")


@dataclass
class BringUpReport:
    windows_used: int = 0
    windows_skipped_static: int = 0
    attempts: int = 0
    rejections: dict = field(default_factory=dict)
    R_IC: list | None = None
    bg: list | None = None
    fit_rms_deg: float | None = None
    validation_rms_deg: float | None = None
    done_t_ns: int | None = None


class HandEyeBringUp:
    """Collects windows, runs the DA3 start-up call on them in the model worker, estimates R_IC."""

    def __init__(self, model: DepthModel, cfg: BringUpConfig | None = None) -> None:
        self.model = model
        self.cfg = cfg or BringUpConfig()
        self.frames: deque[Frame] = deque(maxlen=64)
        self.imu_t: deque[int] = deque()
        self.imu_w: deque[np.ndarray] = deque()
        self.imu_a: deque[np.ndarray] = deque()
        self.windows: list[RotationWindow] = []
        self.result: HandEyeResult | None = None
        self.report = BringUpReport()
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
        self.frames.append(f)

    def _window(self) -> list[Frame] | None:
        if not self.frames:
            return None
        t = np.array([f.t_ns for f in self.frames], np.int64)
        last = int(t[-1])
        n = self.cfg.window_images
        start = last - int(round((n - 1) * self.cfg.window_spacing_s * 1e9))
        if self._last_start is not None and start - self._last_start < self.cfg.window_gap_s * 1e9:
            return None
        picked = []
        for k in range(n):
            ideal = start + int(round(k * self.cfg.window_spacing_s * 1e9))
            j = int(np.argmin(np.abs(t - ideal)))
            if abs(int(t[j]) - ideal) > 30_000_000:
                return None
            picked.append(self.frames[j])
        if not self.imu_t or self.imu_t[0] > picked[0].t_ns or self.imu_t[-1] < picked[-1].t_ns:
            return None
        self._last_start = start
        return picked

    def next_job(self) -> Callable[[], Any] | None:
        """A closure for the model worker: DA3 on the newest window -> RotationWindow (or None)."""
        if self.done:
            return None
        frames = self._window()
        if frames is None:
            return None
        t = np.fromiter(self.imu_t, np.int64, len(self.imu_t))
        w, a = np.array(self.imu_w), np.array(self.imu_a)
        model, cfg = self.model, self.cfg

        def job() -> RotationWindow | None:
            pre = Preintegrator(np.zeros(3), np.zeros(3))
            ints = [pre.integrate(t, w, a, int(frames[0].t_ns), int(f.t_ns)) for f in frames[1:]]
            if np.degrees(np.linalg.norm(_log(ints[-1].dR))) < cfg.min_rotation_deg:
                return None
            pred = model.predict(list(frames))
            return RotationWindow(np.array([pred.T_CW[k][:3, :3].T for k in range(1, len(frames))]),
                                  np.array([p.dR for p in ints]), np.array([p.J_R_bg for p in ints]),
                                  np.zeros(3))

        return job

    def on_result(self, rw: RotationWindow | None, t_ns: int) -> bool:
        """Add a finished window; returns True once R_IC is estimated and validated."""
        if rw is None:
            self.report.windows_skipped_static += 1
            return False
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


def _log(R: np.ndarray) -> np.ndarray:
    from runtime.geometry import so3_log

    return so3_log(R)
