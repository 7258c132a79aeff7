"""The tracking pipeline: KLT front-end, the filter(s) with their native initializers, and the
feed-forward start-up through the buffered-replay handoff. Driven by runtime.scheduler."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drivers.events import Frame, ImuSample
from models.depth_model import DepthModel
from runtime.config import DavioConfig
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
        rig: calib.Rig with camera, T_IC, time offset and IMU noise (T_IC may be withheld: identity
            prior, refined online; see runtime.ffinit.handeye for the withheld bring-up).
        model: a DepthModel for the feed-forward start-up, or None for the native initializer only.
    """

    def __init__(self, rig: Any, model: DepthModel | None = None, config: DavioConfig | None = None) -> None:
        self.rig = rig
        self.config = config or DavioConfig()
        cfg = self.config
        self.tracker = KltTracker(rig.camera, cfg.tracker)
        self.time_offset_s = float(rig.time_offset_s or 0.0)
        T_IC = rig.T_IC if rig.T_IC is not None else np.eye(4)
        self.T_IC = np.asarray(T_IC, float)
        msckf_cfg = cfg.msckf.with_imu_noise(getattr(rig, "imu", None))

        def make_filter(native: bool) -> MsckfEstimator:
            inits: list = []
            if native:
                inits.append(StaticInitializer(cfg.static_init, getattr(rig, "imu", None)))
                if cfg.use_dynamic_init:
                    inits.append(DynamicInitializer(rig.camera, self.T_IC, cfg.dynamic_init,
                                                    getattr(rig, "imu", None), self.time_offset_s))
            return MsckfEstimator(rig, msckf_cfg, initializers=inits)

        startup_cfg = cfg.startup
        if model is None and startup_cfg.feedforward:
            from dataclasses import replace

            startup_cfg = replace(startup_cfg, feedforward=False)
        self.startup = StartupManager(make_filter, startup_cfg, self.time_offset_s)
        self.ffinit = None
        if model is not None and startup_cfg.feedforward:
            self.ffinit = FeedForwardInitializer(model, self.T_IC[:3, :3], self.T_IC[:3, 3],
                                                 self.time_offset_s, cfg.ffinit)
        self.published: list[Published] = []
        self.stats = TrackingStats()

    def on_imu(self, sample: ImuSample) -> list[Published]:
        out = self.startup.on_imu(sample)
        self.published += out
        return out

    def on_frame(self, frame: Frame) -> list[Published]:
        res = self.tracker.track(frame)
        self.stats.frames += 1
        self.stats.tracks_total += len(res.ids)
        if len(res.ids) == 0:
            self.stats.frames_without_tracks += 1
        out = self.startup.on_tracks(int(frame.t_ns), res.ids, res.uv, frame)
        self.published += out
        return out

    def next_model_job(self) -> Callable[[], Any] | None:
        """A feed-forward attempt on the newest window, when one is due (run by the model worker)."""
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

        def job() -> Any:
            return ffinit.solve(frames, t, w, a)

        return job

    def on_model_result(self, result: Any) -> None:
        if isinstance(result, Exception):
            self.stats.ff_exceptions.append(f"{type(result).__name__}: {result}")
            return
        self.startup.on_feedforward(result)

    def report(self) -> dict:
        """Counters of the tracker, the start-up and the publishing filter."""
        from dataclasses import asdict

        rep = {"tracking": asdict(self.stats), "startup": asdict(self.startup.report)}
        filt = self.startup.publisher or self.startup.native
        rep["filter"] = filt.report()
        rep["tracking"]["mean_tracks_per_frame"] = self.stats.tracks_total / max(self.stats.frames, 1)
        return rep
