"""Scheduler: every event reaches the pipeline in order, model results are applied at a
deterministic sensor time with FastClock whatever the worker's speed, failures are reported."""
from __future__ import annotations

import random
import time

import pytest

from runtime.errors import DataError, DavioError
from runtime.events import Frame, ImuSample
from runtime.scheduler import FastClock, PacedClock, Scheduler


def _events(n_imu=400, imu_period=5_000_000, frame_every=10):
    ev = []
    for k in range(n_imu):
        ev.append(ImuSample(k * imu_period, (0.0, 0.0, 0.0), (0.0, 0.0, 9.81)))
        if k % frame_every == 0:
            ev.append(Frame(k * imu_period, None))
    return ev


class TracePipeline:
    def __init__(self, worker_delay):
        self.trace = []
        self.requests = 0
        self.worker_delay = worker_delay
        self.last_t = None

    def on_imu(self, s):
        self.trace.append(("imu", s.t_ns))
        self.last_t = s.t_ns
        return []

    def on_frame(self, f):
        self.trace.append(("frame", f.t_ns))
        self.last_t = f.t_ns
        return [f.t_ns]

    def next_model_job(self):
        if self.requests >= 3 or self.last_t is None or self.last_t < 200_000_000 * (self.requests + 1):
            return None
        self.requests += 1
        t_req, delay = self.last_t, self.worker_delay()

        def job():
            time.sleep(delay)
            return ("result", t_req)

        return job

    def on_model_result(self, res):
        self.trace.append(("model", res[1], self.last_t))


def test_fast_clock_is_deterministic_and_lossless():
    rng = random.Random(0)
    traces = []
    for delays in ((lambda: 0.0), (lambda: rng.uniform(0.0, 0.05))):
        pipe = TracePipeline(delays)
        outputs = []
        rep = Scheduler(FastClock(model_latency_s=0.25), queue_size=16, on_output=outputs.append).run(
            _events(), pipe)
        traces.append(pipe.trace)
        assert rep.imu_samples == 400 and rep.frames == 40 and rep.model_jobs == 3
        assert [o[0] for o in outputs] == [e[1] for e in pipe.trace if e[0] == "frame"]
    assert traces[0] == traces[1]
    models = [e for e in traces[0] if e[0] == "model"]
    # applied at the first event at or after request time + 0.25 s of sensor time
    for _, t_req, t_applied in models:
        assert t_req + 250_000_000 <= t_applied + 5_000_000 and t_applied - t_req < 250_000_000 + 5_000_000
    sensor = [e[1] for e in traces[0] if e[0] != "model"]
    assert sensor == sorted(sensor) and len(sensor) == 440


def test_request_stop_ends_the_run_after_the_event_being_processed():
    """Stopped from on_output at the frame of t = 0.5 s: nothing after it is processed, though the intake had
    queued more; the model job in flight (requested at 0.45 s, due at 0.7 s) still finishes and counts."""
    pipe = TracePipeline(lambda: 0.0)
    sched = Scheduler(FastClock(model_latency_s=0.25), queue_size=64)

    def on_output(out):
        if out[0] >= 500_000_000:
            sched.request_stop()

    sched.on_output = on_output
    rep = sched.run(_events(), pipe)
    sensor = [e for e in pipe.trace if e[0] != "model"]
    assert sensor[-1] == ("frame", 500_000_000) and rep.frames == 11 and rep.imu_samples == 101
    assert rep.stopped_early and rep.sensor_s == 0.5
    assert [e for e in pipe.trace if e[0] == "model"][-1] == ("model", 450_000_000, 500_000_000)
    full = Scheduler(FastClock(model_latency_s=0.25), queue_size=64).run(
        _events(), TracePipeline(lambda: 0.0))
    assert not full.stopped_early and full.frames == 40


def test_a_stop_starts_no_model_job_and_ends_a_quiet_source_and_is_cleared_after_the_run():
    """Stopped at the step that would request the first model job: none is started (a DA3 inference after
    the stop). A source that stops sending (a quiet live camera) does not hold the stop up. The request is
    cleared when the run returns: the same scheduler runs again to the end."""
    import threading

    class FrameStepJobs(TracePipeline):        # asks for its model jobs on the frames' steps only
        def next_model_job(self):
            return super().next_model_job() if self.trace and self.trace[-1][0] == "frame" else None

    pipe = FrameStepJobs(lambda: 0.0)
    sched = Scheduler(FastClock(model_latency_s=0.25), queue_size=64)
    sched.on_output = lambda out: out[0] >= 200_000_000 and sched.request_stop()
    rep = sched.run(_events(), pipe)
    assert rep.stopped_early and rep.model_jobs == 0 and pipe.requests == 0 and rep.frames == 5

    release, finished = threading.Event(), []

    def quiet():
        yield from _events(n_imu=50)
        release.wait(30)        # the source goes quiet; a stop must not wait for it
        finished.append(True)

    sched = Scheduler(FastClock(model_latency_s=0.25), queue_size=64)
    sched.on_output = lambda out: out[0] >= 200_000_000 and sched.request_stop()
    rep = sched.run(quiet(), TracePipeline(lambda: 0.0))
    assert rep.stopped_early and not finished
    release.set()
    sched.on_output = None
    again = sched.run(_events(), TracePipeline(lambda: 0.0))
    assert not again.stopped_early and again.frames >= 40


class SolvePipeline(TracePipeline):
    """Alternates model jobs and jobs that call no model (a start-up re-solve: job.model_call False)."""

    def next_model_job(self):
        job = super().next_model_job()
        if job is not None and self.requests % 2 == 0:
            job.model_call = False
        return job


def test_fast_clock_applies_a_job_without_a_model_call_after_the_solve_latency():
    pipe = SolvePipeline(lambda: 0.0)
    Scheduler(FastClock(model_latency_s=0.25, solve_latency_s=0.05), queue_size=16).run(_events(), pipe)
    # applied before the first event at or after the release time (the trace holds the event before it)
    latency = [t_applied - t_req for kind, t_req, t_applied in
               (e for e in pipe.trace if e[0] == "model")]
    assert len(latency) == 3
    assert 245_000_000 <= latency[0] < 250_000_000 and 245_000_000 <= latency[2] < 250_000_000
    assert 45_000_000 <= latency[1] < 50_000_000      # the second job called no model


def test_paced_clock_waits_for_sensor_time():
    clock = PacedClock(speed=10.0)
    t0 = time.monotonic()
    clock.wait_until(0)
    clock.wait_until(500_000_000)  # 0.5 s of sensor time at 10x = 0.05 s
    assert time.monotonic() - t0 >= 0.045
    with pytest.raises(DavioError):
        PacedClock(speed=0)


def test_intake_error_is_reported_not_swallowed():
    def broken():
        yield ImuSample(0, (0, 0, 0), (0, 0, 9.81))
        raise DataError("frame 3 unreadable", "cam0/data.csv", 4)

    with pytest.raises(DavioError, match="unreadable"):
        Scheduler(FastClock()).run(broken(), TracePipeline(lambda: 0.0))


def test_an_unexpected_exception_in_the_sensor_thread_ends_the_run_loudly():
    """A bug in a driver (any exception, not only DataError) must not look like a shorter recording."""
    from runtime.scheduler import IntakeFailure

    def buggy():
        for k in range(50):
            yield ImuSample(k * 5_000_000, (0, 0, 0), (0, 0, 9.81))
        raise ValueError("index out of range in the image reader")

    pipe = TracePipeline(lambda: 0.0)
    sched = Scheduler(FastClock())
    with pytest.raises(IntakeFailure, match=r"unexpected ValueError in the sensor thread: index out of"):
        sched.run(buggy(), pipe)
    assert sched.report.imu_samples == 50   # what came before the failure was processed


def test_failed_model_job_is_delivered_as_an_exception():
    class Failing(TracePipeline):
        def next_model_job(self):
            if self.requests:
                return None
            self.requests += 1

            def job():
                raise RuntimeError("boom")

            return job

        def on_model_result(self, res):
            self.trace.append(("model", res))

    pipe = Failing(lambda: 0.0)
    Scheduler(FastClock(0.1)).run(_events(100), pipe)
    got = [e[1] for e in pipe.trace if e[0] == "model"]
    assert len(got) == 1 and isinstance(got[0], RuntimeError)


def test_live_queue_keeps_newest_frames_and_every_imu_sample():
    from runtime.scheduler import _END, EventQueue

    q = EventQueue(maxsize=4, max_frames=2)
    for k in range(6):
        q.put(Frame(k, None))
        q.put(ImuSample(k, (0, 0, 0), (0, 0, 0)))
    q.close()
    out = []
    while (ev := q.get()) is not _END:
        out.append(ev)
    frames = [e.t_ns for e in out if isinstance(e, Frame)]
    imu = [e.t_ns for e in out if isinstance(e, ImuSample)]
    assert frames == [4, 5] and q.frames_dropped == 4
    assert imu == list(range(6)) and q.imu_overflow > 0


def test_per_frame_time_counts_the_imu_work_since_the_previous_frame():
    """The filter runs a frame's updates from on_imu: a frame's time holds that work, not only on_frame's."""

    class SlowImuPipeline(TracePipeline):
        def on_imu(self, s):
            t_end = time.perf_counter() + 0.0015      # 1.5 ms of work per sample
            while time.perf_counter() < t_end:
                pass
            return super().on_imu(s)

    rep = Scheduler(FastClock(model_latency_s=0.25), queue_size=16).run(
        _events(n_imu=60, frame_every=10), SlowImuPipeline(lambda: 0.0))
    assert rep.frames == 6 and len(rep.per_frame_ms) == 6
    # every frame after the first follows 10 samples of 1.5 ms each
    assert min(rep.per_frame_ms[1:]) >= 10 * 1.5


def test_a_step_s_events_reach_on_event_after_the_poses_that_step_published():
    """The events a step found (here: one per frame) wait until on_output has had the step's poses, so a
    supervisor reading both in order never gets a reset before the last pose of the segment it ends."""
    from types import SimpleNamespace

    from runtime.run_events import RunEvents

    order: list = []

    class EventfulPipeline(TracePipeline):
        def __init__(self):
            super().__init__(lambda: 0.0)
            self.startup, self.prior, self.rig_check, self.bringup = None, None, None, None
            self.events = RunEvents(self, lambda ev: order.append(("event", ev.t_ns)))

        def on_frame(self, f):
            out = super().on_frame(f)
            self.events._emit(f.t_ns, "reset", "test")      # found while the step runs
            assert order[-1:] != [("event", f.t_ns)]        # not handed on yet
            return [SimpleNamespace(t_ns=t) for t in out]

        def next_model_job(self):
            return None

    pipe = EventfulPipeline()
    sched = Scheduler(FastClock(0.0), on_output=lambda out: order.extend(("pose", p.t_ns) for p in out))
    sched.run(_events(n_imu=40), pipe)
    frames = [t for kind, t in pipe.trace if kind == "frame"]
    assert order == [x for t in frames for x in (("pose", t), ("event", t))]
    assert not pipe.events.hold and pipe.events.pending == []


def test_events_found_before_an_error_or_ctrl_c_still_reach_on_event_and_the_error_is_raised():
    from runtime.run_events import RunEvents

    got: list = []

    class FailingPipeline(TracePipeline):
        def __init__(self):
            super().__init__(lambda: 0.0)
            self.startup, self.prior, self.rig_check, self.bringup = None, None, None, None
            self.events = RunEvents(self, got.append)

        def on_frame(self, f):
            super().on_frame(f)
            self.events._emit(f.t_ns, "rig_finding", "found in the failing step")
            raise KeyboardInterrupt

        def on_imu(self, s):
            super().on_imu(s)
            if s.t_ns == 5_000_000:
                self.events.imu_gap(s.t_ns, 0.2, 0)       # said at once
            if s.t_ns == 10_000_000:
                self.events.imu_gap(s.t_ns, 0.1, 0)       # gathered: said when the data ends
            return []

        def next_model_job(self):
            return None

    pipe = FailingPipeline()
    events = [ImuSample(k * 5_000_000, (0.0, 0.0, 0.0), (0.0, 0.0, 9.81)) for k in range(3)]
    events.append(Frame(15_000_000, None))
    with pytest.raises(KeyboardInterrupt):
        Scheduler(FastClock(0.0)).run(events, pipe)
    assert [(e.kind, e.t_ns) for e in got] == [("imu_gap", 5_000_000), ("rig_finding", 15_000_000),
                                               ("imu_gap", 15_000_000)]
    assert pipe.events.pending == [] and not pipe.events.hold
