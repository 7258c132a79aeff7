"""A DAVIO session fed by your own drivers: push images and IMU samples, get metric poses back.

    from calib import load_rig
    from runtime.session import Session

    with Session(load_rig("camchain.yaml"), on_pose=lambda p: print(p.t_ns, p.T_MI[:3, 3])) as s:
        for kind, t_ns, data in my_sensor():           # your driver: IMU and grey images, int64 ns
            if kind == "imu":
                s.add_imu(t_ns, data.gyro, data.accel)  # rad/s, m/s^2, IMU frame
            else:
                s.add_image(t_ns, data)                 # (H, W) uint8, the rig camera's size
    print(s.result.pipeline.report())                   # counters, timings (after the with-block)

Pushed samples go through a bounded live queue (every IMU sample kept, the oldest waiting image dropped and
counted when tracking falls behind) into the same scheduler and pipeline as `davio run`. Poses arrive
through `on_pose` (called on the session's thread) and through `poses()`; each carries the odometry-frame
pose T_OI, the map-frame pose T_MI with the live map correction, and the 6x6 covariance of
[rotation (body frame), position]. `poses()` holds at most `max_unread_poses` poses not read yet: beyond
that the oldest unread pose is dropped and counted (`unread_poses_dropped`), so a caller that uses only
`on_pose`, or never reads, does not grow memory over a long run. The moments a supervisor must hear of (a
filter began publishing, it diverged and was reset, the rig given is wrong) arrive through `on_event`
(runtime.run_events). `davio run` replays recordings through `Session.replay`.
"""
from __future__ import annotations

import math
import queue
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from runtime.config import DavioConfig
from runtime.errors import ConfigError, DataError, DavioError, caused_by_interrupt
from runtime.events import Frame, ImuSample
from runtime.pipeline import VioPipeline
from runtime.scheduler import FastClock, LiveClock, PacedClock, Scheduler, SchedulerReport


@dataclass(frozen=True)
class Pose:
    """One published IMU state.

    Attributes:
        t_ns: IMU-clock time (ns); t_cam_ns: the camera time of the frame it followed.
        T_OI: (4,4) IMU pose in the odometry frame O (gravity-aligned, z up).
        T_MI: (4,4) IMU pose in the map frame M with the map correction in effect when published.
        v_OI: (3,) velocity in O, m/s.
        covariance: (6,6) covariance of [rotation error (body frame, rad), position (m)], or None.
        source: who published ("native:static", "feedforward", ...); segment: filter restarts before it.
        correction_version: the map correction's version (0: none yet).
        T_PI: (4,4) IMU pose in a prior map's frame (`prior_map`), or None: no prior map, or this
            segment not localised in it yet.
    """

    t_ns: int
    t_cam_ns: int
    T_OI: np.ndarray
    T_MI: np.ndarray
    v_OI: np.ndarray
    covariance: np.ndarray | None
    source: str
    segment: int
    correction_version: int
    T_PI: np.ndarray | None = None


@dataclass
class SessionResult:
    """How a session ended: the pipeline (estimates, report()), the scheduler's counters, and the status
    ("complete", "interrupted" or "failed", with the reason)."""

    pipeline: VioPipeline
    scheduler: SchedulerReport
    status: str = "complete"
    reason: str | None = None


_CLOSE = object()
UNIT_CHECK_SAMPLES = 50
"""IMU samples the stamp-unit and accelerometer-unit checks of `add_imu` look at (the first ones)."""
_POSE_POLL_S = 0.1
"""How often a waiting `poses()` looks whether the session ended."""
UNIT_CHECK_IMAGES = 5
"""Images the stamp-unit check of `add_image` looks at (the first ones)."""


class Session:
    """DAVIO on pushed sensor data (live) or on a recording's events (replay).

    Args:
        rig: the calibration (`calib.Rig`): camera intrinsics, T_IC (None: bring-up with a model).
        model: a DepthModel (DA3 ONNX graph or emulated) for the feed-forward start-up and the map;
            None for tracking with the native initializer only.
        config: DavioConfig (defaults: the paper's numbers).
        on_pose: called with each published Pose (on the session's scheduler thread).
        map_sink: receives every map commit (`tools.run_map.MapOutput.sink`), optional.
        max_pending_frames: images waiting for the tracker before the oldest is dropped (live).
        max_unread_poses: poses `poses()` keeps for the caller (default 12000, ten minutes at 20 Hz);
            beyond that the oldest unread one is dropped and counted in `unread_poses_dropped`.
        prior_map: an earlier run's map to localise this one in (`tools.map_archive.align.
            prior_map_localizer(path)`, or a `runtime.graph.relocalize.PriorMapLocalizer`): poses then
            carry T_PI once localised. Needs a model and mapping.
        on_event: called with each runtime.run_events.RunEvent (on the session's scheduler thread, after
            the poses published in the same step): a filter began publishing, the publishing filter
            diverged and was reset, a rig finding (a gyroscope in deg/s, a wrong camera-IMU rotation or time
            offset), the bring-up's estimate, a prior-map localisation, features lost and back, images
            dropped, IMU gaps; `pipeline.events.log` keeps them too. An exception it raises stops the
            session, as one from on_pose does.
    """

    def __init__(self, rig: Any, model: Any = None, config: DavioConfig | None = None,
                 on_pose: Callable[[Pose], None] | None = None, map_sink: Any = None,
                 max_pending_frames: int = 2, max_unread_poses: int = 12_000, prior_map: Any = None,
                 on_event: Callable[[Any], None] | None = None) -> None:
        if rig is None or getattr(rig, "camera", None) is None:
            raise ConfigError("a session needs the camera intrinsics (rig.camera); see calib.load_rig")
        whole = isinstance(max_unread_poses, (int, np.integer)) and not isinstance(max_unread_poses, bool)
        if not whole or max_unread_poses < 1:
            raise ConfigError(f"max_unread_poses must be a whole number >= 1, got {max_unread_poses!r}")
        self.rig = rig
        self.config = config or DavioConfig()
        self.pipeline = VioPipeline(rig, model, self.config, map_sink=map_sink, prior_map=prior_map,
                                    on_event=on_event)
        self.on_pose = on_pose
        self.max_pending_frames = max_pending_frames
        self._poses: queue.Queue[Pose] = queue.Queue(maxsize=int(max_unread_poses))
        #: poses dropped from `poses()` because more than `max_unread_poses` were waiting unread
        self.unread_poses_dropped = 0
        self._inbox: queue.Queue[Any] | None = None
        self._thread: threading.Thread | None = None
        self._scheduler: Scheduler | None = None
        self._error: BaseException | None = None
        self._error_raised = False
        self._closed = False
        self._closing = False                   # close() began: no push or start from here on
        self._start_lock = threading.Lock()     # an IMU thread and a camera thread may push first together
        self._imu_head: list[tuple[int, np.ndarray]] | None = []    # the first samples, for the unit checks
        self._image_head: list[int] | None = []
        self._scheduled_running = False    # a replay or run_live is running (stop_replay acts on it)
        self.result: SessionResult | None = None

    # -- outputs -------------------------------------------------------------------------------
    def _emit(self, published: list) -> None:
        causal = self.pipeline.causal[len(self.pipeline.causal) - len(published):]
        for p, (T_MI, version, _) in zip(published, causal, strict=True):
            pose = Pose(int(p.t_ns), int(p.t_cam_ns), p.T_OI, T_MI, np.asarray(p.v_OI), p.covariance,
                        p.source, p.segment, version, self.pipeline.prior_pose(p.segment, int(p.t_ns), T_MI))
            self._queue_pose(pose)
            if self.on_pose is not None:
                self.on_pose(pose)

    def _queue_pose(self, pose: Pose) -> None:
        """Queue a pose for `poses()`; when the queue is full, the oldest unread pose makes room."""
        while True:
            try:
                self._poses.put_nowait(pose)
                return
            except queue.Full:
                try:
                    self._poses.get_nowait()
                    self.unread_poses_dropped += 1
                except queue.Empty:
                    pass

    def poses(self, timeout: float | None = 0.0) -> Iterator[Pose]:
        """The poses published since the last call (waits up to `timeout` s for the first one; None: until
        one comes); at most the newest `max_unread_poses`, the older ones counted in
        `unread_poses_dropped`."""
        try:
            yield self._first_pose(timeout)
        except queue.Empty:
            return
        while True:
            try:
                yield self._poses.get_nowait()
            except queue.Empty:
                return

    def _first_pose(self, timeout: float | None) -> Pose:
        """The next pose, waiting up to `timeout` (None: until one comes); queue.Empty on time-out, or once
        the session is closed or its thread failed (no pose can come then)."""
        if timeout == 0:
            return self._poses.get_nowait()
        deadline = None if timeout is None else time.monotonic() + float(timeout)
        while True:
            wait = _POSE_POLL_S if deadline is None else min(_POSE_POLL_S, deadline - time.monotonic())
            if wait <= 0:
                raise queue.Empty
            try:
                return self._poses.get(timeout=wait)
            except queue.Empty:
                if self._closed or self._error is not None:
                    raise

    # -- replay (what `davio run` uses) -------------------------------------------------------
    def replay(self, events: Iterable[ImuSample | Frame], paced: bool = False, speed: float = 1.0,
               model_latency_s: float = 0.5, progress: Callable[[float], None] | None = None,
               keep_partial: bool = False) -> SessionResult:
        """Run a recording's time-ordered events on this thread: as fast as possible with a deterministic
        simulated model latency, or paced at `speed` x sensor rate. With `keep_partial`, Ctrl-C and a
        DavioError end the run early with the status saying so; without, they propagate."""
        clock = PacedClock(speed) if paced else FastClock(model_latency_s)
        self._scheduler = Scheduler(clock, progress=progress, on_output=self._emit)
        return self._run_scheduled(events, keep_partial)

    def stop_replay(self) -> bool:
        """End the `replay` or `run_live` running on this session before its next event, or within 0.1 s
        when none comes (e.g. from `on_pose`): what was processed counts, the result's scheduler report
        says `stopped_early`. Returns False, doing nothing, when neither is running (a session fed by
        `add_*` ends with `close()`)."""
        if not self._scheduled_running or self._scheduler is None:
            return False
        self._scheduler.request_stop()
        return True

    def run_live(self, events: Iterable[ImuSample | Frame], progress: Callable[[float], None] | None = None,
                 keep_partial: bool = True) -> SessionResult:
        """Run a live driver's events on this thread as they arrive (bounded queue: the oldest waiting
        image is dropped and counted when tracking falls behind; model results apply when ready)."""
        self._scheduler = Scheduler(LiveClock(), live=True, max_pending_frames=self.max_pending_frames,
                                    progress=progress, on_output=self._emit)
        return self._run_scheduled(events, keep_partial)

    def _run_scheduled(self, events: Iterable[ImuSample | Frame], keep_partial: bool) -> SessionResult:
        status, reason = "complete", None
        self._scheduled_running = True
        try:
            rep = self._scheduler.run(events, self.pipeline)
        except DavioError as exc:
            if not keep_partial:
                raise
            rep, status, reason = self._scheduler.report, "failed", str(exc)
        except (KeyboardInterrupt, Exception) as exc:   # Ctrl-C, also one surfacing through a C extension
            if not (keep_partial and caused_by_interrupt(exc)):
                raise
            rep, status = self._scheduler.report, "interrupted"
            reason = f"interrupted after {rep.sensor_s:.1f} s of data"
        finally:
            self._scheduled_running = False
        self.result = SessionResult(self.pipeline, rep, status, reason)
        return self.result

    # -- live push -----------------------------------------------------------------------------
    def start(self) -> Session:
        """Start the live scheduler thread (done by the first add_* or by `with`); DavioError once closed."""
        with self._start_lock:
            if self._closed or self._closing:
                raise DavioError("the session is closed: start a new Session for more data")
            if self._thread is None:
                self._inbox = queue.Queue()
                self._scheduler = Scheduler(LiveClock(), live=True,
                                            max_pending_frames=self.max_pending_frames, on_output=self._emit)
                self._thread = threading.Thread(target=self._run_live, name="davio-session", daemon=True)
                self._thread.start()
        return self

    def _incoming(self) -> Iterator[Any]:
        while True:
            ev = self._inbox.get()
            if ev is _CLOSE:
                return
            yield ev

    def _run_live(self) -> None:
        try:
            rep = self._scheduler.run(self._incoming(), self.pipeline)
            self.result = SessionResult(self.pipeline, rep)
        except BaseException as exc:  # noqa: BLE001 - handed to the caller by add_* / close
            self._error = exc
            self.result = SessionResult(self.pipeline, self._scheduler.report, "failed",
                                        f"{type(exc).__name__}: {exc}")

    def _push(self, ev: Any) -> None:
        if self._error is not None:
            self._error_raised = True
            raise DavioError(f"the session stopped: {self._error}") from self._error
        self.start()
        with self._start_lock:     # close() puts its marker under this lock: no event lands behind it
            if self._closed or self._closing:
                raise DavioError("the session is closed: start a new Session for more data")
            self._inbox.put(ev)

    def add_imu(self, t_ns: int, gyro: Any, accel: Any, lost_before: int = 0) -> None:
        """One IMU sample: int64 ns stamp (the camera's clock domain, see rig.time_offset_s), gyro in
        rad/s and accel in m/s^2 in the IMU frame. Non-finite values are counted and dropped by the filter.
        `lost_before`: samples your driver lost right before this one (a sequence-number gap, a queue
        overflow): the filter counts the gap (an imu_gap event) and no start-up window spans it."""
        g, a = _vector3(gyro, "gyro", t_ns), _vector3(accel, "accel", t_ns)
        t = _stamp(t_ns)
        whole = isinstance(lost_before, (int, np.integer)) and not isinstance(lost_before, bool)
        if not whole or lost_before < 0:
            raise DataError(f"add_imu at {t_ns}: lost_before must be a whole number >= 0, got "
                            f"{lost_before!r}")
        if self._imu_head is not None:
            self._check_imu_units(t, a)
        self._push(ImuSample(t, g, a, lost_before=int(lost_before)))

    def _check_imu_units(self, t: int, accel: np.ndarray) -> None:
        """Over the first UNIT_CHECK_SAMPLES samples: stamps in ns (not s, ms or us) and an accelerometer in
        m/s^2 (not g), as the file drivers check them; DataError with the fix otherwise (the filter would
        take the samples as out of order, or publish a wrong scale, without a word)."""
        from runtime.units import accel_looks_like_g, check_stamp_units, repeated_stamps_cause

        head = self._imu_head
        head.append((t, accel))
        if len(head) < UNIT_CHECK_SAMPLES:
            return
        self._imu_head = None
        stamps = np.array([x[0] for x in head], np.int64)
        distinct = len(np.unique(stamps))
        if distinct < len(stamps) // 2:
            raise DataError(f"add_imu: {distinct} distinct stamps in the first {len(stamps)} samples: "
                            + repeated_stamps_cause(stamps))
        check_stamp_units(stamps, "IMU", "Session.add_imu")
        accel = np.array([x[1] for x in head])
        g = accel_looks_like_g(accel[np.isfinite(accel).all(axis=1)])   # a NaN sample would make it NaN
        if g is not None:
            raise DataError(f"add_imu: the accelerometer's median norm is {g:.2f}: it looks like g, not "
                            "m/s^2; multiply it by 9.80665")

    def add_image(self, t_ns: int, image: np.ndarray) -> None:
        """One grey image (H, W) uint8 of the rig camera's size, stamped at mid-exposure (int64 ns)."""
        img = np.asarray(image)
        cam = self.rig.camera
        if img.dtype != np.uint8 or img.ndim != 2:
            raise DataError(f"add_image needs a grey (H, W) uint8 image, got {img.dtype} {img.shape}")
        if img.shape != (cam.height, cam.width):
            raise DataError(f"image size {img.shape[1]}x{img.shape[0]} differs from the calibration's "
                            f"{cam.width}x{cam.height}")
        t = _stamp(t_ns)
        if self._image_head is not None:
            self._image_head.append(t)
            if len(self._image_head) >= UNIT_CHECK_IMAGES:
                from runtime.units import check_stamp_units

                stamps, self._image_head = np.array(self._image_head, np.int64), None
                check_stamp_units(stamps, "camera", "Session.add_image")
        # a copy: the image is held for the start-up and mapping windows, and a driver that reuses one
        # buffer for every frame (V4L2 mmap, cap.read(buf)) would change the images already queued
        self._push(Frame(t, np.array(img, order="C", copy=True), 0))

    def close(self, timeout_s: float = 60.0) -> SessionResult:
        """Process what was pushed, stop the threads, map the windows still queued; returns the result.
        A second call returns the same result. Raises DavioError("the session stopped: ...") when the
        session's thread failed (an exception in `on_pose`, an internal error) and the caller was not told
        yet by an add_*; the result (status "failed") stays in `self.result`."""
        with self._start_lock:    # a push from another thread now fails instead of starting a scheduler
            if self._closed:
                return self.result
            self._closing = True
            if self._thread is not None:
                self._inbox.put(_CLOSE)
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                raise DavioError(f"the session did not stop within {timeout_s:g} s")
            self._thread = None
        if self.result is None:
            self.result = SessionResult(self.pipeline, SchedulerReport())
        if self.result.status == "complete":
            self.pipeline.finish_mapping()
        self._closed = True
        if self._error is not None and not self._error_raised:
            self._error_raised = True
            raise DavioError(f"the session stopped: {self._error}") from self._error
        return self.result

    def __enter__(self) -> Session:
        return self.start()

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if exc_type is None:
            self.close()
            return
        try:                                   # an exception is on its way out: do not replace it
            self.close()
        except DavioError:
            pass


def _vector3(value: Any, what: str, t_ns: Any) -> np.ndarray:
    """A (3,) float64 copy of an IMU vector, or a DataError naming the sample."""
    try:
        v = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DataError(f"add_imu at {t_ns}: {what} is not numeric ({exc})") from None
    if v.size != 3:
        raise DataError(f"add_imu at {t_ns}: {what} needs 3 values (x, y, z), got shape {v.shape}")
    return v.reshape(3)


def _stamp(t_ns: Any) -> int:
    if isinstance(t_ns, float) and not math.isfinite(t_ns) or isinstance(t_ns, bool):
        raise DataError(f"stamp {t_ns!r} is not an integer number of nanoseconds")
    try:
        t = int(t_ns)
    except (TypeError, ValueError, OverflowError):
        raise DataError(f"stamp {t_ns!r} is not an integer number of nanoseconds") from None
    if t != t_ns or not 0 <= t < 2**63:
        raise DataError(f"stamp {t_ns!r} is not a non-negative integer number of nanoseconds below 2^63")
    return t
