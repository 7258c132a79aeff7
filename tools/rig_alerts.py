"""Rig findings said as a run finds them, not only in its end-of-run summary: an operator of `davio live`
or `davio calibrate` on a module learns of a gyroscope in deg/s or an inverted camera-IMU rotation while the
rig is in hand, and a long replay says it when it happens. The lines are the summary's own
(tools.run_summary.rig_lines); each kind of finding is said once."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict
from typing import Any


def _kind(line: str) -> str:
    """A finding's kind: its line up to the first colon ("GYROSCOPE SCALE (tracked features)")."""
    return line.split(":", 1)[0]


class RigAlerts:
    """Call with the data time (s) after each frame, on the pipeline's thread; at most once a data second it
    reads the pipeline's start-up, rig-check and bring-up counters and passes each new kind of finding,
    prefixed with the data time, to `say`. An error in doing so (a closed stderr, say) stops the alerts, not
    the run: `error` holds it.

    Args:
        pipeline: the run's runtime.pipeline.VioPipeline.
        say: where a line goes (e.g. a print to stderr).
        rig_offset_s: the rig file's camera-IMU time offset (s; None: none given).
    """

    def __init__(self, pipeline: Any, say: Callable[[str], None], rig_offset_s: float | None = None) -> None:
        self.pipeline, self.say, self.rig_offset_s = pipeline, say, rig_offset_s
        self.said: list[str] = []
        self._kinds: set[str] = set()
        self._next_s = 0.0
        self.error: str | None = None

    def __call__(self, sensor_s: float) -> None:
        if self.error is not None or sensor_s < self._next_s:
            return
        self._next_s = sensor_s + 1.0
        try:
            self._look(sensor_s)
        except Exception as exc:    # a reporting aid: it never ends the run (the summary still says all)
            self.error = f"{type(exc).__name__}: {exc}"

    def _look(self, sensor_s: float) -> None:
        from tools.run_summary import rig_lines

        for line in rig_lines(self._state(), self.rig_offset_s):
            if _kind(line) not in self._kinds:
                self._kinds.add(_kind(line))
                self.said.append(line)
                self.say(f"at {sensor_s:.1f} s: {line}")

    def _state(self) -> dict:
        pipe, state = self.pipeline, {}
        if pipe.startup is not None:
            rep = pipe.startup.report
            state["startup"] = {k: getattr(rep, k) for k in (
                "ff_rejections", "ff_rejection_first", "time_offset_findings", "time_offset_adopted_s",
                "time_offset_first", "ff_time_offset_first", "ff_time_offset_s")}
        if pipe.rig_check is not None:
            rep = pipe.rig_check.report
            state["rig_check"] = {k: getattr(rep, k) for k in ("gyro_scale", "extrinsics_rotation", "error")}
        if pipe.bringup is not None and not pipe.bringup.done:
            state["bringup"] = asdict(pipe.bringup.report)
        return state


def chain(*calls: Callable[[float], None] | None) -> Callable[[float], None]:
    """One progress callback calling each given one in turn (None skipped)."""
    live = [c for c in calls if c is not None]

    def call(sensor_s: float) -> None:
        for c in live:
            c(sensor_s)

    return call
