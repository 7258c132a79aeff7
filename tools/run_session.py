"""One end-to-end run: a driver through the VIO pipeline under the scheduler, with progress."""
from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Any

from runtime.config import DavioConfig
from runtime.errors import DavioError
from runtime.pipeline import VioPipeline
from runtime.scheduler import FastClock, PacedClock, Scheduler, SchedulerReport


@dataclass
class RunResult:
    """The pipeline (its estimates), the scheduler's counters and how the run ended.

    `status` is "complete", "interrupted" (Ctrl-C / SIGTERM) or "failed" (a DavioError after the run
    started, `reason` says which); the pipeline then holds what was computed up to that moment.
    """

    pipeline: VioPipeline
    scheduler: SchedulerReport
    status: str = "complete"
    reason: str | None = None


def run_pipeline(driver: Any, model: Any, config: DavioConfig, paced: bool = False, speed: float = 1.0,
                 model_latency_s: float = 0.5, show_progress: bool = True, seconds: float | None = None,
                 rig: Any = None, map_sink: Any = None, keep_partial: bool = False) -> RunResult:
    """Run `driver` (events, rig) through a VioPipeline; returns the pipeline and scheduler report.

    With a model and mapping enabled, the windows still queued when the recording ends are mapped
    after the scheduler returns (`map_sink` receives every commit). With `keep_partial`, Ctrl-C
    (KeyboardInterrupt) and a DavioError during the run end it early and the result says so
    (`status`, `reason`) with everything computed until then; without, they propagate."""
    pipe = VioPipeline(rig if rig is not None else driver.rig, model, config, map_sink=map_sink)
    clock = PacedClock(speed) if paced else FastClock(model_latency_s)
    events = driver.events()
    if seconds is not None:
        events = _first_seconds(events, seconds)
    progress = None
    bar = None
    if show_progress and sys.stderr.isatty():
        from rich.progress import Progress

        bar = Progress(transient=True)
        task = bar.add_task("running", total=seconds)
        bar.start()

        def progress(s: float) -> None:
            who = _status(pipe)
            bar.update(task, completed=s, description=f"running ({who})")
    elif show_progress:
        last = [-1]

        def progress(s: float) -> None:
            if int(s) // 5 != last[0]:
                last[0] = int(s) // 5
                print(f"  t = {s:6.1f} s  published {len(pipe.published):5d} poses"
                      f"  ({_status(pipe)})", file=sys.stderr, flush=True)
    scheduler = Scheduler(clock, progress=progress)
    status, reason = "complete", None
    try:
        rep = scheduler.run(events, pipe)
    except KeyboardInterrupt:
        if not keep_partial:
            raise
        rep, status = scheduler.report, "interrupted"
        reason = f"interrupted after {scheduler.report.sensor_s:.1f} s of data"
    except DavioError as exc:
        if not keep_partial:
            raise
        rep, status, reason = scheduler.report, "failed", str(exc)
    finally:
        if bar is not None:
            bar.stop()
    if status == "complete":
        pending = len(pipe.map_queue) if pipe.map_queue is not None else 0
        if pending and show_progress:
            print(f"  mapping the {pending} window(s) still queued at the end of the recording",
                  file=sys.stderr, flush=True)
        pipe.finish_mapping()
    return RunResult(pipe, rep, status, reason)


def _status(pipe: VioPipeline) -> str:
    if pipe.startup is None:
        return "calibration bring-up"
    return pipe.startup.report.published_by or "starting"


def _first_seconds(events: Any, seconds: float) -> Any:
    t0 = None
    for ev in events:
        if t0 is None:
            t0 = ev.t_ns
        if (ev.t_ns - t0) * 1e-9 > seconds:
            return
        yield ev
