"""One tracking run of `davio bench trajectory`, recorded so that any mapper can be replayed on it offline.

Tracking does not depend on mapping (the feed-forward start-up off: the model serves only the mapper,
tests/runtime/test_pipeline_mapping.py), so one run gives every variant's inputs. The run is the live
pipeline itself (`VioPipeline` under the `Scheduler` with `FastClock(model_latency_s)`), with mapping on
and a stand-in mapper that only records: the keyframe windows, the single-worker queue (its drops), the
sensor time each mapping result is applied at and how many poses were published before it are then
exactly those of a live run with a real mapper. `trajectory_replay.replay` feeds the recorded windows to a
real mapper in the same order and applies its commits at the recorded points.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from runtime.config import DavioConfig
from runtime.mapping.mapper import MappingStats
from runtime.mapping.windows import MappingWindow
from runtime.pipeline import VioPipeline

DEFAULT_MODEL_LATENCY_S = 0.5
"""Sensor seconds between a mapping request and its result (`davio run`'s default FastClock)."""


@dataclass
class MappingSlot:
    """A window the live mapper processed, in processing order.

    Attributes:
        window: the keyframe window (frames and published camera poses T_OC).
        applied: (poses published before the result was applied, the pipeline's last IMU time then, ns)
            for a result applied during tracking; None for a result the live stream never saw (windows
            mapped after the recording ended, and the job in flight when it ended).
        after_end: mapped by `finish_mapping` after the recording ended (its commit reaches the final
            trajectory); False with `applied` None: the job in flight at the end (its result is dropped
            by the scheduler).
    """

    window: MappingWindow
    applied: tuple[int, int] | None = None
    after_end: bool = False


@dataclass
class TrackingRun:
    """A tracking run and the mapping schedule a live run would follow.

    Attributes:
        published: every published state (runtime.startup.Published), in publication order.
        slots: the processed windows with their schedule (MappingSlot), processing order.
        windows_offered, windows_dropped: windows the keyframe selector completed / the queue dropped.
        first_t_ns, last_t_ns: first and last event of the recording (sensor clock; the IMU's when the
            IMU starts first).
        first_publish_t_ns: the first published state's time (None if nothing was published).
        time_offset_ns: the rig's camera-to-IMU time offset (t_imu = t_cam + offset).
        frames, tracking_s: frames tracked and the wall time of the run (rendering included).
        report: the pipeline's report (tracking, start-up, filter, mapping-queue counters).
    """

    published: list
    slots: list[MappingSlot]
    windows_offered: int
    windows_dropped: int
    first_t_ns: int
    last_t_ns: int
    first_publish_t_ns: int | None
    time_offset_ns: int
    frames: int
    tracking_s: float
    report: dict = field(default_factory=dict)

    @property
    def windows(self) -> list[MappingWindow]:
        return [s.window for s in self.slots]

    def keyframe_t_ns(self, segment: int | None = None) -> np.ndarray:
        """Sorted unique camera stamps of the processed windows' frames (of one segment, or all)."""
        ts = [w.t_ns for w in self.windows if segment is None or w.segment == segment]
        return np.unique(np.concatenate(ts)) if ts else np.zeros(0, np.int64)


class _Marker:
    """What the recording mapper returns: the index of the slot it recorded."""

    def __init__(self, index: int) -> None:
        self.index = index


class _RecordingMapper:
    """A stand-in Mapper: records each window it is given, maps nothing."""

    def __init__(self, slots: list[MappingSlot]) -> None:
        self.slots = slots
        self.stats = MappingStats(matcher="none")
        self.backend = None

    def process(self, window: MappingWindow) -> _Marker:
        self.stats.windows_processed += 1
        self.slots.append(MappingSlot(window))
        return _Marker(len(self.slots) - 1)


class _NoModel:
    """The pipeline needs a model object to run its mapping queue; the recording mapper never calls it."""

    K_rect = np.eye(3)

    def predict(self, *args: Any, **kwargs: Any) -> Any:  # pragma: no cover - never called
        raise RuntimeError("the recording run has no depth model")


class _RecordingPipeline(VioPipeline):
    """VioPipeline that notes when (sensor time, poses published so far) each mapping result is applied."""

    def __init__(self, rig: Any, config: DavioConfig) -> None:
        self.slots: list[MappingSlot] = []
        self.last_event_ns: int | None = None
        super().__init__(rig, _NoModel(), config,
                         mapper_factory=lambda *a, **k: _RecordingMapper(self.slots))

    def on_imu(self, sample: Any) -> list:
        self.last_event_ns = int(sample.t_ns)
        return super().on_imu(sample)

    def on_frame(self, frame: Any) -> list:
        self.last_event_ns = int(frame.t_ns)
        return super().on_frame(frame)

    def on_model_result(self, result: Any) -> None:
        if self._job_kind == "mapping" and isinstance(result, _Marker):
            self.slots[result.index].applied = (len(self.published), int(self._last_t))
        super().on_model_result(result)

    def finish_mapping(self) -> int:
        n = len(self.slots)
        done = super().finish_mapping()
        for s in self.slots[n:]:
            s.after_end = True
        return done


def tracking_config(config: DavioConfig | None = None) -> DavioConfig:
    """The run's configuration: `config` (defaults) with mapping on and the feed-forward start-up off."""
    cfg = config or DavioConfig()
    return replace(cfg, startup=replace(cfg.startup, feedforward=False),
                   mapping=replace(cfg.mapping, enabled=True))


def record_tracking(rec: Any, config: DavioConfig | None = None,
                    model_latency_s: float = DEFAULT_MODEL_LATENCY_S, events: Any = None) -> TrackingRun:
    """Track `rec` (a driver: `events()`, `rig`) through the live pipeline and record the mapping schedule.

    Args:
        config: the run's configuration (mapping on and feed-forward off are forced, `tracking_config`).
        model_latency_s: the FastClock latency of a mapping job (sensor seconds).
        events: the events to feed (default `rec.events()`), e.g. a list kept by a test.
    """
    from runtime.scheduler import FastClock, Scheduler

    pipe = _RecordingPipeline(rec.rig, tracking_config(config))
    t0 = time.perf_counter()
    sched = Scheduler(FastClock(model_latency_s))
    rep = sched.run(iter(events) if events is not None else rec.events(), pipe)
    pipe.finish_mapping()
    tracking_s = time.perf_counter() - t0
    first = rep.first_t_ns if rep.first_t_ns is not None else 0
    last = pipe.last_event_ns if pipe.last_event_ns is not None else first
    st = pipe.startup.report if pipe.startup is not None else None
    mstats = pipe.report().get("mapping", {})
    return TrackingRun(list(pipe.published), pipe.slots, int(mstats.get("windows_offered", 0)),
                       int(mstats.get("windows_dropped_queue", 0)), int(first), int(last),
                       None if st is None else st.first_publish_t_ns,
                       int(round(pipe.time_offset_s * 1e9)), rep.frames, tracking_s, pipe.report())
