"""The tracking pipeline: KLT front-end, the filter(s) with their native initializers, and the
feed-forward start-up through the buffered-replay handoff. Driven by runtime.scheduler."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from models.depth_model import DepthModel
from runtime.bringup import HandEyeBringUp
from runtime.config import DavioConfig
from runtime.errors import ConfigError
from runtime.events import Frame, ImuSample
from runtime.ffinit.initializer import FeedForwardInitializer
from runtime.msckf.estimator import MsckfEstimator
from runtime.msckf.init_dynamic import DynamicInitializer
from runtime.msckf.init_static import StaticInitializer
from runtime.msckf.tracker import KltTracker
from runtime.startup import Published, StartupManager


@dataclass
class TrackingStats:
    """Per-run tracking counters."""

    frames: int = 0
    tracks_total: int = 0
    frames_without_tracks: int = 0
    ff_exceptions: list = field(default_factory=list)


class VioPipeline:
    """Tracker + StartupManager (+ feed-forward initializer when a depth model is given).

    Args:
        rig: calib.Rig with camera, T_IC, time offset and IMU noise. With T_IC withheld, a hand-eye
            bring-up (runtime.bringup) first estimates R_IC from DA3 and the IMU; tracking then
            starts with zero lever arm and time offset and online calibration of all three.
        model: a DepthModel for the feed-forward start-up, or None for the native initializer only.
    """

    def __init__(self, rig: Any, model: DepthModel | None = None, config: DavioConfig | None = None) -> None:
        self.config = config or DavioConfig()
        self.model = model
        self.tracker = KltTracker(rig.camera, self.config.tracker)
        self.published: list[Published] = []
        self.stats = TrackingStats()
        self.bringup: HandEyeBringUp | None = None
        self._job_kind = ""
        self._last_t = 0
        if rig.T_IC is None:
            if model is None:
                raise ConfigError("the camera-IMU extrinsics are withheld: calibration-withheld bring-up "
                                  "needs a depth model (pass a DA3 graph) or give T_IC in the rig")
            self.bringup = HandEyeBringUp(model)
            self.rig = rig
            self.startup = None
            self.ffinit = None
        else:
            self._start_tracking(rig, self.config)

    def _start_tracking(self, rig: Any, cfg: DavioConfig, bg_prior: np.ndarray | None = None) -> None:
        """Build the filters (native initializers armed) and the feed-forward start-up for `rig`."""
        self.rig = rig
        self.time_offset_s = float(rig.time_offset_s or 0.0)
        self.T_IC = np.asarray(rig.T_IC, float)
        msckf_cfg = cfg.msckf.with_imu_noise(getattr(rig, "imu", None))
        imu_noise = getattr(rig, "imu", None)
        static_cfg = cfg.static_init
        if static_cfg.wait_for_jerk is None:   # OpenVINS: a filter with ZUPT can start standing still
            static_cfg = replace(static_cfg, wait_for_jerk=not msckf_cfg.try_zupt)

        def make_filter(native: bool) -> MsckfEstimator:
            inits: list = []
            if native:
                inits.append(StaticInitializer(static_cfg, imu_noise))
                if cfg.use_dynamic_init:
                    inits.append(DynamicInitializer(rig.camera, self.T_IC, cfg.dynamic_init, imu_noise,
                                                    self.time_offset_s))
            return MsckfEstimator(rig, msckf_cfg, initializers=inits)

        startup_cfg = cfg.startup
        if self.model is None and startup_cfg.feedforward:
            startup_cfg = replace(startup_cfg, feedforward=False)
        self.startup = StartupManager(make_filter, startup_cfg, self.time_offset_s)
        self.ffinit = None
        if self.model is not None and startup_cfg.feedforward:
            self.ffinit = FeedForwardInitializer(self.model, self.T_IC[:3, :3], self.T_IC[:3, 3],
                                                 self.time_offset_s, cfg.ffinit)
        self._bg_prior = bg_prior

    def _finish_bringup(self) -> None:
        """Hand-eye done: R_IC estimated, lever arm and time offset zero; the filter refines all three."""
        res = self.bringup.result
        T_IC = np.eye(4)
        T_IC[:3, :3] = res.R_IC
        rig = self.rig.replace(T_IC=T_IC, time_offset_s=self.rig.time_offset_s or 0.0)
        cfg = replace(self.config, msckf=replace(self.config.msckf, calib_extrinsics=True,
                                                 calib_time_offset=True))
        self.config = cfg
        self._start_tracking(rig, cfg, bg_prior=res.bg)

    def on_imu(self, sample: ImuSample) -> list[Published]:
        self._last_t = int(sample.t_ns)
        if self.startup is None:
            self.bringup.on_imu(sample)
            return []
        out = self.startup.on_imu(sample)
        self.published += out
        return out

    def on_frame(self, frame: Frame) -> list[Published]:
        res = self.tracker.track(frame)
        self.stats.frames += 1
        self.stats.tracks_total += len(res.ids)
        if len(res.ids) == 0:
            self.stats.frames_without_tracks += 1
        if self.startup is None:
            self.bringup.on_frame(frame)
            return []
        out = self.startup.on_tracks(int(frame.t_ns), res.ids, res.uv, frame)
        self.published += out
        return out

    def next_model_job(self) -> Callable[[], Any] | None:
        """A model job when one is due (run by the model worker): a hand-eye window during a
        calibration-withheld bring-up, else a feed-forward attempt on the newest window."""
        if self.startup is None:
            job = self.bringup.next_job()
            self._job_kind = "bringup" if job is not None else self._job_kind
            return job
        self._job_kind = "feedforward"
        if self.ffinit is None:
            return None
        frames = self.startup.window()
        if frames is None:
            return None
        imu = self.startup.imu_for(frames)
        if imu is None:
            return None
        self.startup.note_request()
        ffinit = self.ffinit
        t, w, a = imu
        bg = self._bg_prior

        def job() -> Any:
            return ffinit.solve(frames, t, w, a, bg=bg)

        return job

    def on_model_result(self, result: Any) -> None:
        if isinstance(result, Exception):
            self.stats.ff_exceptions.append(f"{type(result).__name__}: {result}")
            return
        if self._job_kind == "bringup":
            if self.bringup.on_result(result, self._last_t):
                self._finish_bringup()
            return
        self.startup.on_feedforward(result)

    def report(self) -> dict:
        """Counters of the tracker, the start-up and the publishing filter."""
        from dataclasses import asdict

        rep = {"tracking": asdict(self.stats)}
        if self.bringup is not None:
            rep["bringup"] = asdict(self.bringup.report)
        if self.startup is not None:
            rep["startup"] = asdict(self.startup.report)
            rep["filter"] = (self.startup.publisher or self.startup.native).report()
        rep["tracking"]["mean_tracks_per_frame"] = self.stats.tracks_total / max(self.stats.frames, 1)
        return rep
