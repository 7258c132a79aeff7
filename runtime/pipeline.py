"""The tracking pipeline: KLT front-end, the filter(s) with their native initializers, the
feed-forward start-up through the buffered-replay handoff, and the mapping queue. Driven by
runtime.scheduler: one model worker serves start-up and mapping, start-up windows first."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from models.depth_model import DepthModel
from runtime.bringup import HandEyeBringUp
from runtime.config import DavioConfig
from runtime.errors import ConfigError, caused_by_interrupt
from runtime.events import Frame, ImuSample
from runtime.ffinit.extension import TrackSet
from runtime.ffinit.initializer import FeedForwardInitializer
from runtime.ffinit.time_offset_check import imu_lead_s
from runtime.geometry.se3 import make_pose
from runtime.graph.correction import CorrectionTimeline, final_corrections
from runtime.graph.prior_frame import PriorFrame
from runtime.imu.rate_quantiles import RateQuantiles
from runtime.mapping.mapper import MAX_ERROR_MESSAGES, MapCommit, Mapper, MappingStats
from runtime.mapping.windows import MappingWindow, WindowBuilder, WindowQueue
from runtime.msckf.estimator import MsckfEstimator
from runtime.msckf.init_dynamic import DynamicInitializer
from runtime.msckf.init_static import StaticInitializer
from runtime.msckf.init_turning import TurningInitializer
from runtime.msckf.tracker import KltTracker
from runtime.pose_history import CausalView, PoseHistory, PublishedView
from runtime.rig_check import TwoViewRigCheck
from runtime.run_events import RunEvent, RunEvents
from runtime.startup import Published, StartupManager


@dataclass
class TrackingStats:
    """Per-run tracking counters."""

    frames: int = 0
    tracks_total: int = 0
    frames_without_tracks: int = 0
    imu_out_of_range: int = 0
    """IMU samples beyond any MEMS IMU's range (MAX_GYRO_RAD_S, MAX_ACCEL_M_S2): dropped before the
    initializers and filters (a corrupt value, or a gyroscope in deg/s)."""
    ff_exceptions: list = field(default_factory=list)
    """The first MAX_ERROR_MESSAGES failed start-up jobs (feed-forward, bring-up, re-solve), as text..."""
    ff_errors: int = 0
    """...and how many failed in all."""

    def start_up_failed(self, text: str) -> None:
        self.ff_errors += 1
        if len(self.ff_exceptions) < MAX_ERROR_MESSAGES:
            self.ff_exceptions.append(text)


MAX_GYRO_RAD_S = 100.0
"""Largest angular rate accepted per axis (rad/s; MEMS gyroscopes end at 35-70 rad/s, 2000-4000 deg/s)."""
MAX_ACCEL_M_S2 = 1000.0
"""Largest specific force accepted per axis (m/s^2; about 100 g, beyond any VIO-grade accelerometer)."""


class VioPipeline:
    """Tracker + StartupManager (+ feed-forward initializer when a depth model is given).

    Args:
        rig: calib.Rig with camera, T_IC, time offset and IMU noise. With T_IC withheld, a hand-eye
            bring-up (runtime.bringup) first estimates R_IC from the camera's rotations (DA3's, or
            two-view fits of the tracked features without a model) and the IMU's; tracking then
            starts with zero lever arm and time offset and online calibration of all three.
        model: a DepthModel for the feed-forward start-up and the mapping, or None for the native
            initializer only (no map).
        map_sink: called by the model worker with every map commit (the run's map archive).
        mapper_factory: builds the Mapper (tests and benchmarks inject one); default `Mapper`.
        prior_map: a `runtime.graph.relocalize.PriorMapLocalizer` over an earlier run's map: each
            committed submap is localised in it, and published poses get their pose in its frame
            (`prior_pose`, runtime.graph.prior_frame). Needs mapping (a model, mapping on).
        on_event: called with each runtime.run_events.RunEvent (a new publisher, a reset, a rig finding,
            the bring-up's estimate, a prior-map localisation, features lost and back, images dropped live,
            IMU gaps) on the pipeline's thread; `events.log` keeps them either way.
    """

    def __init__(self, rig: Any, model: DepthModel | None = None, config: DavioConfig | None = None,
                 map_sink: Callable[[MapCommit, MappingStats], None] | None = None,
                 mapper_factory: Callable[..., Mapper] | None = None, prior_map: Any = None,
                 on_event: Callable[[RunEvent], None] | None = None) -> None:
        self.config = config or DavioConfig()
        #: the run's events (runtime.run_events): a new publisher, a reset, a rig finding, ...
        self.events = RunEvents(self, on_event, rig.time_offset_s, self.config.msckf.max_imu_gap_s,
                                max_imu_outage_s=self.config.msckf.max_imu_outage_s)
        self.model = model
        self.map_sink = map_sink
        self._mapper_factory = mapper_factory or Mapper
        self.mapper: Mapper | None = None
        self.windows: WindowBuilder | None = None
        self.map_queue: WindowQueue | None = None
        if model is not None and self.config.mapping.enabled:
            self.windows = WindowBuilder(self.config.mapping)
            self.map_queue = WindowQueue(self.config.mapping.max_pending_windows)
            self.map_stats = MappingStats()
            self._frames_waiting: dict[int, Frame] = {}
        self.prior: PriorFrame | None = None
        if prior_map is not None:
            if self.windows is None:
                raise ConfigError("a prior map needs the mapping: a depth model with mapping on (the run's "
                                  "submaps are what is localised in it)")
            if not self.config.mapping.graph or not self.config.revisits.enabled:
                raise ConfigError("a prior map needs the submaps' centre views, which the submap graph keeps "
                                  "for revisits: set mapping.graph and revisits.enabled to true")
            self.prior = PriorFrame(prior_map, prior_map.source)
        #: live odometry-to-map correction (eq. correction), one timeline per odometry segment
        self.corrections: dict[int, CorrectionTimeline] = {}
        #: every published state and its map-frame pose as published, in compact columns (254 B a pose);
        #: `published` and `causal` are read-only sequence views of it
        self.history = PoseHistory()
        #: per published state: (T_MI (4,4) as published in the map frame, version, fraction)
        self.causal: CausalView = self.history.causal
        #: final per-node corrections: submap index -> (segment, centre camera t_ns, T_MO (4,4))
        self.node_corrections: dict[int, tuple[int, int, np.ndarray]] = {}
        self.tracker = KltTracker(rig.camera, self.config.tracker)
        self.published: PublishedView = self.history.published
        self.stats = TrackingStats()
        self.bringup: HandEyeBringUp | None = None
        self._job_kind = ""
        self._last_t = 0
        self._lost_carried = 0   # lost_before of IMU samples dropped (out of range, behind), for the next one
        self._imu_newest_ns: int | None = None
        self._gyro_rates = RateQuantiles()   # the run's |gyro|: a gyroscope in deg/s reads 57.3x
        #: without the feed-forward start-up (no model): the gyro's scale and the camera-IMU rotation checked
        #: from the tracks (with it, the start-up's DA3 windows check both)
        self.rig_check: TwoViewRigCheck | None = None
        if rig.T_IC is None:   # without a model, the bring-up takes the camera's rotations from the tracks
            self.bringup = HandEyeBringUp(model, self.config.bringup,
                                          focal_px=float(np.sqrt(rig.camera.fx * rig.camera.fy)))
            self.rig = rig
            self.startup = None
            self.ffinit = None
        else:
            self._start_tracking(rig, self.config)
            if self.ffinit is None and self.config.rig_check.enabled:   # no DA3 windows: the tracks check
                self.rig_check = TwoViewRigCheck(self.T_IC[:3, :3], self.time_offset_s,
                                                 float(np.sqrt(rig.camera.fx * rig.camera.fy)),
                                                 self.config.rig_check, ffcfg=self.config.ffinit)

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
                if cfg.turning_init.enabled:
                    inits.append(TurningInitializer(rig.camera, self.T_IC, cfg.turning_init, imu_noise,
                                                    self.time_offset_s))
                if cfg.use_dynamic_init:
                    inits.append(DynamicInitializer(rig.camera, self.T_IC, cfg.dynamic_init, imu_noise,
                                                    self.time_offset_s))
            est = MsckfEstimator(rig, msckf_cfg, initializers=inits)
            est.set_time_offset(self.time_offset_s)    # the rig's, or one the start-up adopted since
            return est

        startup_cfg = cfg.startup
        if self.model is None and startup_cfg.feedforward:
            startup_cfg = replace(startup_cfg, feedforward=False)
        adopt = self._adopt_time_offset if cfg.ffinit.correct_time_offset else None
        self.startup = StartupManager(make_filter, startup_cfg, self.time_offset_s,
                                      imu_lead_s=imu_lead_s(cfg.ffinit),
                                      adopt_time_offset=adopt)
        self.ffinit = None
        if self.model is not None and startup_cfg.feedforward:
            self.ffinit = FeedForwardInitializer(self.model, self.T_IC[:3, :3], self.T_IC[:3, 3],
                                                 self.time_offset_s, cfg.ffinit)
        self._bg_prior = bg_prior

    def _adopt_time_offset(self, time_offset_s: float) -> None:
        """The start-up's windows agree on a camera-IMU time offset other than the rig's: later windows and
        filters use it (the start-up and its native filter took it up already)."""
        self.time_offset_s = float(time_offset_s)
        if self.ffinit is not None:
            self.ffinit.time_offset_s = self.time_offset_s

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
        self.events.calibration_estimated(self._last_t, self.bringup.report)

    def on_imu(self, sample: ImuSample) -> list[Published]:
        self._last_t = int(sample.t_ns)
        if self.events.start_ns is None:
            self.events.start_ns = self._last_t
        g, a = sample.gyro, sample.accel   # NaN compares False: the filter counts those itself
        if (abs(g[0]) > MAX_GYRO_RAD_S or abs(g[1]) > MAX_GYRO_RAD_S or abs(g[2]) > MAX_GYRO_RAD_S
                or abs(a[0]) > MAX_ACCEL_M_S2 or abs(a[1]) > MAX_ACCEL_M_S2 or abs(a[2]) > MAX_ACCEL_M_S2):
            self.stats.imu_out_of_range += 1
            self._lost_carried += int(getattr(sample, "lost_before", 0) or 0)   # a driver's gap flag stays
            return []
        self._gyro_rates.add(g[0], g[1], g[2])
        if self._imu_newest_ns is not None and sample.t_ns <= self._imu_newest_ns:
            if sample.lost_before:     # stamped behind the newest: dropped by the filter, its gap flag stays
                self._lost_carried += int(sample.lost_before)
                sample = replace(sample, lost_before=0)
        else:
            self._imu_newest_ns = int(sample.t_ns)
            if self._lost_carried:
                sample = replace(sample, lost_before=int(sample.lost_before) + self._lost_carried)
                self._lost_carried = 0
        self.events.imu_sample(sample)
        if self.startup is None:
            self.bringup.on_imu(sample)
            return []
        if self.rig_check is not None and not self.rig_check.done:
            self.rig_check.on_imu(sample.t_ns, g, a)
        out = self.startup.on_imu(sample)
        self._publish_causal(out)
        self.events.after_imu(self._last_t)
        if self.windows is not None and out:
            self._offer_keyframes(out)
        return out

    def on_frame(self, frame: Frame) -> list[Published]:
        res = self.tracker.track(frame)
        self.stats.frames += 1
        self.stats.tracks_total += len(res.ids)
        if len(res.ids) == 0:
            self.stats.frames_without_tracks += 1
        if self.events.start_ns is None:
            self.events.start_ns = int(frame.t_ns)
        if self.startup is None:
            self.bringup.on_frame(frame)
            self.bringup.on_tracks(res.t_ns, res.ids, res.xy)
            self.events.after_frame(int(frame.t_ns), len(res.ids))
            return []
        if self.rig_check is not None and not self.rig_check.done:
            self.rig_check.on_tracks(res.t_ns, res.ids, res.xy)
        out = self.startup.on_tracks(int(frame.t_ns), res.ids, res.uv, frame)
        self._publish_causal(out)
        if self.windows is not None:
            self._frames_waiting[int(frame.t_ns)] = frame
            if len(self._frames_waiting) > 64:   # poses come within a few IMU samples of the frame
                self._frames_waiting.pop(next(iter(self._frames_waiting)))
            if out:
                self._offer_keyframes(out)
        self.events.after_frame(int(frame.t_ns), len(res.ids))
        return out

    # ------------------------------------------------------------------ live map-frame poses
    def _publish_causal(self, out: list[Published]) -> None:
        """Record the published states and their map-frame poses T_MO(t) T_OI(t) as published."""
        for p in out:
            T_OI = p.T_OI
            tl = self.corrections.get(p.segment)
            if tl is None:
                self.history.append(p, T_OI, 0, 1.0)
            else:
                c = tl.apply(int(p.t_ns), T_OI)
                self.history.append(p, c.T_MI, c.version, c.fraction)
        if out:
            self.events.on_published(out)

    def _apply_commit(self, commit: MapCommit) -> None:
        """A map commit defines a new correction from the sensor time it is applied at."""
        seg = commit.submap.segment
        tl = self.corrections.setdefault(seg, CorrectionTimeline())
        t = max(self._last_t, tl.last_commit_ns or 0)
        tl.commit(t, commit.T_MO, commit.version)
        self._record_nodes(commit)
        if self.prior is not None:
            self.prior.update(t)

    def prior_pose(self, segment: int, t_ns: int, T_MI: np.ndarray) -> np.ndarray | None:
        """T_PI (4,4) in the prior map's frame of a pose published at t_ns with map-frame pose T_MI, or
        None (no prior map, or its segment not localised in it yet)."""
        return None if self.prior is None else self.prior.pose(segment, t_ns, T_MI)

    def _record_nodes(self, commit: MapCommit) -> None:
        offset = int(round(self.time_offset_s * 1e9))     # the rig's, or the one the start-up adopted
        for sm in (commit.submap, *commit.changed):
            T_MO = sm.T_MS @ np.linalg.inv(sm.T_OS)
            self.node_corrections[sm.index] = (sm.segment, int(sm.frame_t_ns[sm.centre]) + offset, T_MO)

    def final_poses(self) -> np.ndarray:
        """Every published pose re-exported with the completed corrections (T_MI per state): each
        state gets the final correction of its segment's submaps, interpolated between the submap
        centres around it (runtime.graph.correction.final_corrections); (N,4,4), one array."""
        rows = self.history.rows()
        T_OI = make_pose(rows["R_OI"], rows["p_OI"]).reshape(-1, 4, 4)
        out = T_OI.copy()
        for seg in np.unique(rows["segment"]):
            idx = np.flatnonzero(rows["segment"] == seg)
            nodes = sorted((t, T) for s, t, T in self.node_corrections.values() if s == seg)
            t_nodes = np.array([t for t, _ in nodes], np.int64)
            T_nodes = np.array([T for _, T in nodes]).reshape(-1, 4, 4)
            corr = final_corrections(rows["t_ns"][idx], t_nodes, T_nodes)
            out[idx] = np.matmul(corr, T_OI[idx])
        return out

    # ------------------------------------------------------------------ mapping queue
    def _offer_keyframes(self, out: list[Published]) -> None:
        """Published poses of buffered frames go to the keyframe selector; full windows are queued.
        (The filter publishes a frame's state once the IMU covers its time, often on a later IMU sample.)"""
        for pose in out:
            frame = self._frames_waiting.pop(int(pose.t_cam_ns), None)
            if frame is None:
                continue
            for t in [t for t in self._frames_waiting if t < pose.t_cam_ns]:
                del self._frames_waiting[t]     # older frames never got a pose of their own
            window = self.windows.add(frame, pose.T_OI @ self.T_IC, pose.segment)
            if window is None:
                continue
            self.map_stats.windows_offered += 1
            if self.map_queue.put(window) is not None:
                self.map_stats.windows_dropped_queue += 1

    def _mapping_job(self, window: MappingWindow) -> Callable[[], Any]:
        if self.mapper is None:
            cfg = self.config
            mapper = self._mapper_factory(self.model, self.rig.camera, cfg.mapping, sink=self.map_sink,
                                          graph=cfg.graph if cfg.mapping.graph else False,
                                          revisits=cfg.revisits)
            # one set of counters: the queue's (kept since the first window) and the mapper's
            self.map_stats.matcher = mapper.stats.matcher
            mapper.stats = self.map_stats
            self.mapper = mapper
        mapper = self.mapper

        prior = self.prior

        def job() -> Any:
            result = mapper.process(window)
            if prior is not None and isinstance(result, MapCommit):
                prior.on_submap(result.submap)
            return result

        return job

    def finish_mapping(self) -> int:
        """Map the windows still queued when the recording ended (in the calling thread); returns
        how many were processed. Call after the scheduler returned (no model job in flight). A window whose
        job fails (the model raised, returned the wrong shapes) is counted as the scheduler counts one
        during the run (windows_rejected "exception"), never raised."""
        if self.map_queue is None:
            return 0
        done = 0
        while (window := self.map_queue.pop()) is not None:
            try:
                result = self._mapping_job(window)()
            except Exception as exc:  # noqa: BLE001 - as the model worker does: a failed job is a result
                if caused_by_interrupt(exc):      # Ctrl-C surfacing through a C extension: not a model error
                    raise
                result = exc
            if isinstance(result, Exception):
                st = self.map_stats
                st.reject("exception")
                if len(st.model_errors) < MAX_ERROR_MESSAGES:
                    st.model_errors.append(f"{type(result).__name__}: {result}")
            elif isinstance(result, MapCommit):   # after the last pose: only the final trajectory sees it
                self._record_nodes(result)
            done += 1
            self._note_model_failures()
        self.events.after_mapping(self._last_t)
        return done

    def next_model_job(self) -> Callable[[], Any] | None:
        """A model job when one is due (run by the model worker): a hand-eye window during a
        calibration-withheld bring-up, else a feed-forward attempt on the newest window."""
        if self.startup is None:
            job = self.bringup.next_job()
            self._job_kind = "bringup" if job is not None else self._job_kind
            return job
        job = self._extension_job()
        if job is not None:
            self._job_kind = "extension"
            return job
        job = self._feedforward_job()
        if job is not None:
            self._job_kind = "feedforward"
            return job
        window = self.map_queue.pop() if self.map_queue is not None else None
        if window is None:
            return None
        self._job_kind = "mapping"
        return self._mapping_job(window)

    def _extension_job(self) -> Callable[[], Any] | None:
        """A re-solve of a refused start-up window over a longer span (no model call), or None."""
        if self.ffinit is None:
            return None
        due = self.startup.extension()
        if due is None:
            return None
        seed, stamps = due
        tracks = self.startup.tracks_at(stamps)
        if tracks is None:     # a frame's tracks left the buffer: they will not come back
            self.startup.end_extension("extension_tracks_lost")
            return None
        imu = self.startup.extension_imu(stamps)
        if imu is None:
            return None
        self.startup.note_extension(stamps)
        ffinit, camera = self.ffinit, self.rig.camera
        t, w, a = imu
        bg = self._bg_prior

        def job() -> Any:
            sets = [TrackSet(int(ts), np.asarray(ids), camera.undistort_points(np.asarray(uv, float)))
                    for ts, ids, uv in tracks]
            return ffinit.solve_extended(seed, sets, t, w, a, bg=bg)

        job.model_call = False   # type: ignore[attr-defined]  (a solve: FastClock's solve latency)
        return job

    def _feedforward_job(self) -> Callable[[], Any] | None:
        """A feed-forward attempt on the newest start-up window, or None (also while a refused window
        still waits for a longer re-solve)."""
        if self.ffinit is None or self.startup.extension_pending():
            return None
        frames = self.startup.window()
        if frames is None:
            return None
        imu = self.startup.imu_for(frames)
        if imu is None:
            return None
        self.startup.note_request(frames)
        ffinit = self.ffinit
        t, w, a = imu
        bg = self._bg_prior

        def job() -> Any:
            return ffinit.solve(frames, t, w, a, bg=bg)

        return job

    def on_model_result(self, result: Any) -> None:
        try:
            self._on_model_result(result)
        finally:
            self._note_model_failures()

    def _note_model_failures(self) -> None:
        """Hand the model job failures so far (start-up and mapping) to the run events."""
        st, mp = self.stats, getattr(self, "map_stats", None)
        mapped = sum(mp.windows_rejected.get(k, 0) for k in ("model_error", "exception")) if mp else 0
        if st.ff_errors + mapped:
            first = (st.ff_exceptions or (mp.model_errors if mp else []) or ["?"])[0]
            self.events.model_failures(self._last_t, st.ff_errors + mapped, first)

    def _on_model_result(self, result: Any) -> None:
        if self._job_kind == "mapping":   # the mapper counted it; an exception is a mapping error
            if isinstance(result, Exception):
                st = self.map_stats
                st.reject("exception")          # counted always; the first messages are kept
                if len(st.model_errors) < MAX_ERROR_MESSAGES:
                    st.model_errors.append(f"{type(result).__name__}: {result}")
            elif isinstance(result, MapCommit):
                self._apply_commit(result)
            return
        if isinstance(result, Exception):
            if self._job_kind == "extension":   # no model call failed: the re-solve did; give it up
                self.stats.start_up_failed(f"start-up re-solve: {type(result).__name__}: {result}")
                self.startup.end_extension("exception")
                return
            where = "bring-up: " if self._job_kind == "bringup" else ""
            self.stats.start_up_failed(f"{where}{type(result).__name__}: {result}")
            return
        if self._job_kind == "bringup":
            if self.bringup.on_result(result, self._last_t):
                self._finish_bringup()
            return
        self.startup.on_feedforward(result, extension=self._job_kind == "extension")

    def report(self) -> dict:
        """Counters of the tracker, the start-up and the publishing filter."""
        rep = {"tracking": asdict(self.stats)}
        if self.bringup is not None:
            rep["bringup"] = asdict(self.bringup.report)
        if self.rig_check is not None:
            rep["rig_check"] = {k: v for k, v in asdict(self.rig_check.report).items() if k != "ratios"}
        if self.startup is not None:
            rep["startup"] = asdict(self.startup.report)
            rep["filter"] = (self.startup.publisher or self.startup.native).report()
            # a filter booted by the feed-forward start-up after a reset counts from its own start
            rep["filter"]["scope"] = ("the filter publishing at the end (the native filter when none does), "
                                      "since it started; the run's resets: startup.restarts_after_divergence")
        if self.windows is not None:
            rep["mapping"] = asdict(self.map_stats)
            rep["mapping"]["keyframes"] = self.windows.keyframes
            if self.mapper is not None and self.mapper.backend is not None:
                rep["mapping"]["graph"] = asdict(self.mapper.backend.stats)
            rep["mapping"]["windows_dropped_ids"] = list(self.map_queue.dropped)
        if self.prior is not None:
            rep["prior_map"] = self.prior.report()
        rep["tracking"]["mean_tracks_per_frame"] = self.stats.tracks_total / max(self.stats.frames, 1)
        # the run's |gyro| (runtime.imu.rate_quantiles; a p90 above GYRO_UNITS_P90_RAD_S: deg/s?)
        rep["tracking"]["gyro_rate_median_rad_s"] = self._gyro_rates.quantile(0.5)
        rep["tracking"]["gyro_rate_p90_rad_s"] = self._gyro_rates.quantile(0.9)
        rep["events"] = self.events.report()
        return rep

