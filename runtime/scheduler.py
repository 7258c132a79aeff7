"""Threaded scheduler: sensor intake, tracking and a single model worker, with bounded queues.

Threads:
  * intake: iterates the driver's events into a bounded queue (replay: lossless back-pressure;
    live: IMU lossless, frames keep the newest `max_pending_frames`, drops counted);
  * tracking (the calling thread): feeds the pipeline in sensor-time order and submits model jobs;
  * model worker: runs one job at a time (DA3 + feed-forward solve), never blocking tracking.

Clocks decide pacing and when model results are applied:
  * `PacedClock(speed)`: events are released at sensor rate (wall clock); results apply when ready.
  * `FastClock(model_latency_s, solve_latency_s)`: as fast as possible; a result requested at sensor
    time t applies at the first event with sensor time >= t + model_latency_s (solve_latency_s for a
    job that calls no model: its `model_call` attribute is False; tracking waits for the worker if
    needed) -- deterministic for tests and benchmarks whatever the machine's speed.
The scheduler takes the driver and pipeline through their interfaces and imports neither package.
"""
from __future__ import annotations

import contextlib
import math
import queue
import threading
import time
from array import array
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from runtime.errors import DavioError


class Pipeline(Protocol):
    """What the scheduler drives (runtime.pipeline.VioPipeline)."""

    def on_imu(self, sample: Any) -> list: ...

    def on_frame(self, frame: Any) -> list: ...

    def next_model_job(self) -> Callable[[], Any] | None: ...

    def on_model_result(self, result: Any) -> None: ...


class PacedClock:
    """Releases events at `speed` times the sensor rate; model results apply when ready."""

    deterministic = False

    def __init__(self, speed: float = 1.0) -> None:
        if not (math.isfinite(speed) and speed > 0):     # NaN or inf paced nothing
            raise DavioError(f"speed must be a finite number > 0, got {speed}")
        self.speed = speed
        self._t0: tuple[int, float] | None = None

    def wait_until(self, t_ns: int) -> None:
        if self._t0 is None:
            self._t0 = (t_ns, time.monotonic())
            return
        due = self._t0[1] + (t_ns - self._t0[0]) * 1e-9 / self.speed
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)

    def release_ns(self, t_request_ns: int, model_call: bool = True) -> int | None:
        return None


class LiveClock:
    """Live sensors: events are processed as they arrive; model results apply when ready."""

    deterministic = False

    def wait_until(self, t_ns: int) -> None:
        return None

    def release_ns(self, t_request_ns: int, model_call: bool = True) -> int | None:
        return None


class FastClock:
    """As fast as possible; model results apply `model_latency_s` of sensor time after the request, the
    results of jobs that call no model (a start-up re-solve) `solve_latency_s` after it."""

    deterministic = True

    def __init__(self, model_latency_s: float = 1.0, solve_latency_s: float = 0.1) -> None:
        self.model_latency_s = float(model_latency_s)
        self.solve_latency_s = float(solve_latency_s)

    def wait_until(self, t_ns: int) -> None:
        return None

    def release_ns(self, t_request_ns: int, model_call: bool = True) -> int | None:
        latency = self.model_latency_s if model_call else self.solve_latency_s
        return t_request_ns + int(round(latency * 1e9))


_END = object()


class IntakeFailure(DavioError):
    """The sensor thread stopped on an error: the events after it never reached the pipeline."""


@dataclass
class SchedulerReport:
    """Counters of a scheduled run."""

    events: int = 0
    imu_samples: int = 0
    frames: int = 0
    frames_dropped: int = 0
    model_jobs: int = 0
    model_busy_s: float = 0.0
    imu_overflow: int = 0
    intake_error: str | None = None
    stopped_early: bool = False
    """`Scheduler.request_stop` ended the run before the events did."""
    wall_s: float = 0.0
    sensor_s: float = 0.0
    first_t_ns: int | None = None
    first_frame_t_ns: int | None = None
    last_frame_t_ns: int | None = None
    per_frame_ms: array = field(default_factory=lambda: array("d"))
    """Wall ms of the pipeline per frame: the frame's tracking plus the IMU samples since the previous frame
    (the filter runs a frame's updates when the IMU passes it, from on_imu); 8 bytes a frame."""

    @property
    def image_span_s(self) -> float:
        """Sensor seconds from the first to the last frame (0 without frames)."""
        if self.first_frame_t_ns is None or self.last_frame_t_ns is None:
            return 0.0
        return (self.last_frame_t_ns - self.first_frame_t_ns) * 1e-9

    def as_dict(self) -> dict:
        d = {k: v for k, v in self.__dict__.items() if k != "per_frame_ms"}
        ms = sorted(self.per_frame_ms)
        if ms:
            d["tracking_ms_per_frame_median"] = ms[len(ms) // 2]
            d["tracking_ms_per_frame_p95"] = ms[min(len(ms) - 1, int(0.95 * len(ms)))]
        d["image_span_s"] = self.image_span_s
        # IMU recorded before the first or after the last image is not camera-rate work: the factor
        # counts only the span with images
        span = self.image_span_s
        d["realtime_factor"] = span / self.wall_s if self.wall_s > 0 and span > 0 else None
        return d


class EventQueue:
    """Bounded, thread-safe event queue.

    Replay (max_frames=None): `put` blocks while full (lossless back-pressure). Live
    (max_frames=k): IMU samples are never dropped (the queue grows past its bound rather than lose
    one, counted in `imu_overflow`); when k frames wait already, the oldest waiting frame is dropped
    and counted, so tracking always gets the newest images.
    """

    def __init__(self, maxsize: int, max_frames: int | None = None) -> None:
        self.maxsize = maxsize
        self.max_frames = max_frames
        self._items: deque = deque()
        self._frames = 0
        self._closed = False
        self._cv = threading.Condition()
        self.frames_dropped = 0
        self.imu_overflow = 0

    def put(self, ev: Any) -> None:
        is_frame = hasattr(ev, "image")
        with self._cv:
            if self.max_frames is None:
                while len(self._items) >= self.maxsize and not self._closed:
                    self._cv.wait(0.1)
                if self._closed:
                    return
            else:
                if is_frame and self._frames >= self.max_frames:
                    for i, old in enumerate(self._items):
                        if hasattr(old, "image"):
                            del self._items[i]
                            self._frames -= 1
                            self.frames_dropped += 1
                            break
                if not is_frame and len(self._items) >= self.maxsize:
                    self.imu_overflow += 1
            self._items.append(ev)
            self._frames += is_frame
            self._cv.notify_all()

    def get(self, stop: threading.Event | None = None) -> Any:
        """The next event, or _END once the queue is closed and empty or `stop` is set while it is empty."""
        with self._cv:
            while not self._items:
                if self._closed or (stop is not None and stop.is_set()):
                    return _END
                self._cv.wait(0.1)
            ev = self._items.popleft()
            self._frames -= hasattr(ev, "image")
            self._cv.notify_all()
            return ev

    def close(self) -> None:
        with self._cv:
            self._closed = True
            self._cv.notify_all()


class _ModelWorker(threading.Thread):
    def __init__(self, report: SchedulerReport) -> None:
        super().__init__(name="davio-model", daemon=True)
        self.jobs: queue.Queue = queue.Queue(maxsize=1)
        self.results: queue.Queue = queue.Queue()
        self.report = report

    def run(self) -> None:
        while True:
            item = self.jobs.get()
            if item is _END:
                return
            job_id, job = item
            t0 = time.perf_counter()
            try:
                result = job()
            except Exception as exc:  # a failing job is a result, never a dead worker
                result = exc
            self.report.model_busy_s += time.perf_counter() - t0
            self.results.put((job_id, result))


class Scheduler:
    """Runs a driver through a pipeline with an intake thread and a model worker.

    Args:
        clock: PacedClock or FastClock.
        live: live-sensor queue policy (drop old frames) instead of lossless replay.
        queue_size: bounded intake queue length (events).
        on_output: called with each non-empty list the pipeline returns (published states).
        progress: called with (sensor seconds since start) after each frame.
    """

    def __init__(self, clock: PacedClock | FastClock | LiveClock, live: bool = False, queue_size: int = 2048,
                 max_pending_frames: int = 2, on_output: Callable[[list], None] | None = None,
                 progress: Callable[[float], None] | None = None) -> None:
        self.clock = clock
        self.live = live
        self.queue_size = queue_size
        self.max_pending_frames = max_pending_frames
        self.on_output = on_output
        self.progress = progress
        self.report = SchedulerReport()
        self._stop_requested = threading.Event()

    def request_stop(self) -> None:
        """End `run` before its next event, or within 0.1 s when none comes (from any thread, e.g. an
        `on_output` callback): no model job is started after it, one in flight still finishes and counts.
        The report says so (`stopped_early`). A request made before `run` applies to it; `run` clears the
        request when it returns."""
        self._stop_requested.set()

    def _intake(self, events: Iterable[Any], q: EventQueue, stop: threading.Event) -> None:
        try:
            for ev in events:
                if stop.is_set():
                    break
                q.put(ev)
        except DavioError as exc:
            self.report.intake_error = str(exc)
        except Exception as exc:  # noqa: BLE001 - any failure ends the run loudly, never a short run
            import traceback

            where = traceback.extract_tb(exc.__traceback__)[-1]
            self.report.intake_error = (f"unexpected {type(exc).__name__} in the sensor thread: {exc} "
                                        f"({Path(where.filename).name}:{where.lineno})")
        finally:
            q.close()

    def run(self, events: Iterable[Any], pipeline: Pipeline) -> SchedulerReport:
        """Process every event; returns the report (the pipeline holds the estimates), a new one each run."""
        rep = self.report = SchedulerReport()
        q = EventQueue(self.queue_size, self.max_pending_frames if self.live else None)
        stop = threading.Event()
        intake = threading.Thread(target=self._intake, args=(events, q, stop), name="davio-intake",
                                  daemon=True)
        worker = _ModelWorker(rep)
        worker.start()
        intake.start()
        in_flight: tuple[int, int | None] | None = None  # (job id, release time)
        job_id = 0
        t_first: int | None = None
        imu_ms = 0.0     # the pipeline's time in on_imu since the last frame
        # runtime.run_events.RunEvents, when the pipeline has them: each step's events after its poses
        run_events = getattr(pipeline, "events", None)
        if run_events is not None:
            run_events.hold = True
        t = None
        wall0 = time.perf_counter()
        failed = False
        try:
            while True:
                ev = q.get(self._stop_requested)
                if self._stop_requested.is_set():
                    rep.stopped_early = True
                    break
                if ev is _END:
                    break
                t = int(ev.t_ns)
                if t_first is None:
                    t_first = t
                    rep.first_t_ns = t
                self.clock.wait_until(t)
                # apply a finished model result (deterministically at its release time with FastClock)
                if in_flight is not None:
                    jid, release = in_flight
                    if release is None:
                        try:
                            _, res = worker.results.get_nowait()
                            in_flight = None
                            pipeline.on_model_result(res)
                        except queue.Empty:
                            pass
                    elif t >= release:
                        _, res = worker.results.get()
                        in_flight = None
                        pipeline.on_model_result(res)
                rep.events += 1
                if hasattr(ev, "image"):
                    rep.frames += 1
                    if rep.first_frame_t_ns is None:
                        rep.first_frame_t_ns = t
                    rep.last_frame_t_ns = t
                    t0 = time.perf_counter()
                    out = pipeline.on_frame(ev)
                    rep.per_frame_ms.append(imu_ms + 1e3 * (time.perf_counter() - t0))
                    imu_ms = 0.0
                    if q.frames_dropped and run_events is not None:
                        run_events.frames_dropped(q.frames_dropped, t)
                    if self.progress is not None:
                        self.progress((t - t_first) * 1e-9)
                else:
                    rep.imu_samples += 1
                    t0 = time.perf_counter()
                    out = pipeline.on_imu(ev)
                    imu_ms += 1e3 * (time.perf_counter() - t0)
                if out and self.on_output is not None:
                    self.on_output(out)
                if run_events is not None and run_events.pending:
                    run_events.flush()
                if in_flight is None and not self._stop_requested.is_set():
                    job = pipeline.next_model_job()
                    if job is not None:
                        job_id += 1
                        rep.model_jobs += 1
                        worker.jobs.put((job_id, job))
                        in_flight = (job_id, self.clock.release_ns(t, getattr(job, "model_call", True)))
                rep.sensor_s = (t - t_first) * 1e-9
            if in_flight is not None:   # the recording ended with a job running: its result still counts
                _, res = worker.results.get()
                in_flight = None
                pipeline.on_model_result(res)
        except BaseException:
            failed = True
            raise
        finally:
            self._stop_requested.clear()
            stop.set()
            q.close()
            intake.join(timeout=5)
            worker.jobs.put(_END)
            worker.join(timeout=30)
            rep.frames_dropped = q.frames_dropped
            rep.imu_overflow = q.imu_overflow
            rep.wall_s = time.perf_counter() - wall0
            if run_events is not None:
                if t is not None:     # images dropped and IMU gaps after the last ones said
                    run_events.data_ended(t, q.frames_dropped)
                run_events.hold = False
                if failed:   # Ctrl-C or an error: what was found still goes out; the first error is raised
                    with contextlib.suppress(Exception):
                        run_events.flush()
        if run_events is not None and run_events.pending:   # outside `finally`: a failing callback raises...
            if rep.intake_error is not None:               # ...unless the intake's error is to be raised
                with contextlib.suppress(Exception):
                    run_events.flush()
            else:
                run_events.flush()
        if rep.intake_error is not None:
            raise IntakeFailure(f"sensor intake failed after {rep.sensor_s:.1f} s of data: "
                                f"{rep.intake_error}")
        return rep
