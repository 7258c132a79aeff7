"""One end-to-end run: a driver through the VIO pipeline under the scheduler, with progress."""
from __future__ import annotations

import contextlib
import sys
from typing import Any

from runtime.config import DavioConfig
from runtime.event_window import first_seconds
from runtime.pipeline import VioPipeline
from runtime.session import Session, SessionResult

RunResult = SessionResult
"""The pipeline (its estimates), the scheduler's counters and how the run ended (runtime.session)."""


def run_pipeline(driver: Any, model: Any, config: DavioConfig, paced: bool = False, speed: float = 1.0,
                 model_latency_s: float = 0.5, show_progress: bool = True, seconds: float | None = None,
                 rig: Any = None, map_sink: Any = None, keep_partial: bool = False,
                 on_pose: Any = None, prior_map: Any = None, on_event: Any = None) -> RunResult:
    """Run `driver` (events, rig) through a VioPipeline; returns the pipeline and scheduler report.

    With a model and mapping enabled, the windows still queued when the recording ends are mapped
    after the scheduler returns (`map_sink` receives every commit). With `keep_partial`, Ctrl-C
    (KeyboardInterrupt) and a DavioError during the run end it early and the result says so
    (`status`, `reason`) with everything computed until then; without, they propagate. `on_pose` gets
    every published runtime.session.Pose (e.g. the live view's); `prior_map` (a PriorMapLocalizer) an
    earlier run's map to localise this one in; `on_event` every runtime.run_events.RunEvent (with
    `show_progress` they are also said on stderr as they happen, e.g. a rig finding)."""
    from tools.event_output import EventConsole, chain_events
    from tools.run_outcome import finish_mapping
    from tools.stderr_lines import attempt
    from tools.stderr_lines import say as stderr_say

    progress = None
    bar = None
    say = None
    if show_progress and sys.stderr.isatty():
        from rich.progress import Progress

        bar = Progress(transient=True)
        task = bar.add_task("running", total=seconds)

        def say(line: str) -> None:     # above the bar; an event's text is not rich markup
            attempt(lambda: bar.console.print(line, markup=False, highlight=False))

        def progress(s: float) -> None:
            attempt(lambda: bar.update(task, completed=s, description=f"running ({_status(pipe)})"))
    elif show_progress:
        last = [-1]

        def say(line: str) -> None:
            stderr_say(line)

        def progress(s: float) -> None:
            if int(s) // 5 != last[0]:
                last[0] = int(s) // 5
                stderr_say(f"  t = {s:6.1f} s  published {len(pipe.published):5d} poses  ({_status(pipe)})")
    # events said as they happen (rig findings again in the summary)
    console = EventConsole(lambda line: say(f"  {line}")) if say is not None else None
    # poses go to on_pose; poses() is never read here, so its queue holds one (12000 poses were ~13 MB)
    session = Session(rig if rig is not None else driver.rig, model, config, map_sink=map_sink,
                      on_pose=on_pose, prior_map=prior_map, on_event=chain_events(console, on_event),
                      max_unread_poses=1)
    pipe = session.pipeline
    events = driver.events()
    if seconds is not None:
        events = first_seconds(events, seconds)
    if bar is not None:
        bar.start()
    try:
        res = session.replay(events, paced=paced, speed=speed, model_latency_s=model_latency_s,
                             progress=progress, keep_partial=keep_partial)
    finally:
        if bar is not None:
            with contextlib.suppress(OSError, ValueError):
                bar.stop()
    if res.status == "complete":
        pending = len(pipe.map_queue) if pipe.map_queue is not None else 0
        if pending and show_progress:
            stderr_say(f"  mapping the {pending} window(s) still queued at the end of the recording")
    finish_mapping(res, pipe)
    return res


def _status(pipe: VioPipeline) -> str:
    if pipe.startup is None:
        return "calibration bring-up"
    who = pipe.startup.report.published_by or "starting"
    if pipe.prior is None:
        return who
    seg = pipe.published[len(pipe.published) - 1].segment if len(pipe.published) else 0
    return f"{who}; prior map: {'localised' if pipe.prior.localized(seg) else 'searching'}"


