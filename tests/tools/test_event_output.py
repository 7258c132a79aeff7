"""Where a run's events go (tools.event_output): events.jsonl written as they happen (strict JSON, a failing
disk stops the file and says why), console lines with the data time, the live status line's own line; and a
run on a gyroscope in deg/s says so while it runs."""
from __future__ import annotations

import json
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from runtime.run_events import RunEvent
from tools.event_output import EVENTS_NAME, EventConsole, EventFile, chain_events


def _event(t_s: float = 6.0, **detail) -> RunEvent:
    return RunEvent(1_000_000_000 + int(t_s * 1e9), t_s, "rig_finding",
                    "GYROSCOPE SCALE (tracked features): x",
                    detail or {"key": "gyro_scale", "evidence": "tracks"})


def test_the_file_holds_one_strict_json_object_per_event_as_soon_as_it_happens(tmp_path):
    out = EventFile(tmp_path)
    out(_event(6.0))
    # flushed at once: a reader following the file (or a killed run) sees it before the run ends
    rows = [json.loads(x) for x in (tmp_path / EVENTS_NAME).read_text().splitlines()]
    assert rows == [{"t_ns": 7_000_000_000, "t_s": 6.0, "kind": "rig_finding",
                     "message": "GYROSCOPE SCALE (tracked features): x", "key": "gyro_scale",
                     "evidence": "tracks"}]
    out(_event(7.5, fit=float("nan"), R_IC=np.eye(3)))      # non-finite and numpy values made plain JSON
    out.close()
    text = (tmp_path / EVENTS_NAME).read_text().splitlines()[1]
    row = json.loads(text, parse_constant=lambda c: pytest.fail(f"non-strict {c}"))
    assert row["fit"] is None and row["R_IC"] == np.eye(3).tolist() and out.written == 2
    out(_event(9.0))                 # after close: nothing, no error
    assert out.written == 2 and out.failed is None


def test_a_failing_disk_stops_the_file_and_says_why_not_the_run(tmp_path):
    out = EventFile(tmp_path)

    class Full:
        closed = False

        def write(self, _text):
            raise OSError(28, "No space left on device")

        def close(self):
            self.closed = True

    out._fh = Full()
    out(_event())                     # raises nothing
    assert out.failed == f"{tmp_path / EVENTS_NAME}: No space left on device" and out.written == 0
    out(_event())
    assert out.written == 0


def test_the_console_says_each_event_with_its_data_time_and_an_error_stops_only_the_lines():
    said: list[str] = []
    console = EventConsole(said.append)
    console(_event(6.04))
    assert said == ["at 6.0 s: GYROSCOPE SCALE (tracked features): x"]

    def broken(line: str) -> None:
        raise BrokenPipeError("stderr closed")

    console = EventConsole(broken)
    console(_event())
    assert console.error == "BrokenPipeError: stderr closed" and console.lines == 1
    console(_event())                 # no longer says, raises nothing
    assert console.lines == 1


def test_chain_events_calls_each_callback_in_order():
    seen: list[tuple[str, float]] = []
    call = chain_events(lambda e: seen.append(("a", e.t_s)), None, lambda e: seen.append(("b", e.t_s)))
    call(_event(1.5))
    assert seen == [("a", 1.5), ("b", 1.5)]
    assert chain_events(None, None) is None


def test_the_live_status_line_says_an_event_on_its_own_line(capsys):
    from runtime.startup import StartupReport
    from tools.commands.live import _StatusLine

    status = _StatusLine(None)
    status(1.0)                                   # no session yet: nothing
    status.events(_event(2.0))
    pipe = SimpleNamespace(startup=SimpleNamespace(report=StartupReport()), prior=None, published=[],
                           stats=SimpleNamespace(tracks_total=300, frames=3))
    status.session = SimpleNamespace(pipeline=pipe, _scheduler=None)
    status(2.0)
    lines = capsys.readouterr().err.splitlines()
    assert lines[0] == "  at 2.0 s: GYROSCOPE SCALE (tracked features): x"
    assert "100 tracks" in lines[1]            # the status line follows
    pipe.stats.frames += 20                   # a second of a covered camera: the run's mean would say 13
    status.last -= 2.0                        # (the line is refreshed once a wall second)
    status(3.0)
    assert "   0 tracks" in capsys.readouterr().err
    status.last -= 2.0                        # no frame at all in the last second: a stalled camera
    status(4.0)
    assert "   - tracks" in capsys.readouterr().err


@pytest.mark.slow
def test_a_run_says_a_deg_per_second_gyro_while_it_runs(capsys):
    """9 s of the aggressive preset with its gyro in deg/s and no model: the tracked-feature check names it
    on stderr seconds before the recording ends, as the summary names it at the end, and the event says
    which check found it."""
    from drivers.sim import SimConfig, SimRecording
    from runtime.config import DavioConfig
    from runtime.events import ImuSample
    from runtime.rig_findings import rig_lines
    from tools.run_session import run_pipeline

    rec = SimRecording.from_preset(SimConfig(preset="aggressive", seconds=9.0, seed=4, camera_rate_hz=10.0))

    class DegPerSecond:
        rig = rec.rig

        def events(self):
            for ev in rec.events():
                if isinstance(ev, ImuSample):
                    ev = ImuSample(ev.t_ns, np.asarray(ev.gyro) * np.degrees(1.0), ev.accel)
                yield ev

    # the dynamic initializer's attempts on a wrong gyro cost the test time and change nothing here
    cfg = replace(DavioConfig(), use_dynamic_init=False)
    got: list = []
    res = run_pipeline(DegPerSecond(), None, cfg, show_progress=True, on_event=got.append)
    err = capsys.readouterr().err
    said = [x.strip() for x in err.splitlines() if "GYROSCOPE SCALE" in x]
    assert len(said) == 1 and said[0].startswith("at "), err
    assert float(said[0].split()[1]) < 8.0
    end = [x for x in rig_lines(res.pipeline.report(), None) if x.startswith("GYROSCOPE SCALE (tracked")]
    assert len(end) == 1 and "deg/s" in end[0]
    found = [e for e in got if e.kind == "rig_finding"]
    assert [(e.detail["key"], e.detail["evidence"]) for e in found] == [("gyro_scale", "tracks")]
    assert said[0] == f"at {found[0].t_s:.1f} s: {found[0].message}"
    assert res.pipeline.events.log == got
