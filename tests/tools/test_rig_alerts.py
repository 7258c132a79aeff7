"""Rig findings said while a run goes (tools.rig_alerts): once per kind, with the data time, the same lines
as the end-of-run summary."""
from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from runtime.bringup import BringUpReport
from runtime.rig_check import RigCheckReport
from runtime.startup import StartupReport
from tools.rig_alerts import RigAlerts, chain
from tools.run_summary import rig_lines


def _pipe(startup=None, rig_check=None, bringup=None):
    return SimpleNamespace(startup=None if startup is None else SimpleNamespace(report=startup),
                           rig_check=None if rig_check is None else SimpleNamespace(report=rig_check),
                           bringup=bringup)


def test_each_kind_of_finding_is_said_once_with_the_data_time():
    st, rc = StartupReport(), RigCheckReport()
    said: list[str] = []
    alerts = RigAlerts(_pipe(st, rc), said.append)
    alerts(0.0)
    assert said == []
    st.ff_rejections = {"gyro_scale": 1}
    st.ff_rejection_first = {"gyro_scale": "the gyroscope turns 57.1x as far"}
    alerts(0.5)                  # within the data second of the last look: not read
    assert said == []
    alerts(1.2)
    assert said == ["at 1.2 s: GYROSCOPE SCALE: 1 windows refused, the first: the gyroscope turns 57.1x as "
                    "far. Fix the IMU's units or scale; every filter integrates them too"]
    st.ff_rejections["gyro_scale"] = 5         # the same finding again, with a new count: not said again
    st.ff_rejections["extrinsics_rotation"] = 1   # one window: not yet a finding (as the summary)
    alerts(2.5)
    assert len(said) == 1
    st.ff_rejections["extrinsics_rotation"] = 2
    rc.gyro_scale = "the gyroscope turns 57.9x as far as the tracked features see"
    alerts(3.6)
    assert [s.split(":")[0] for s in said[1:]] == ["at 3.6 s", "at 3.6 s"]
    assert said[1].startswith("at 3.6 s: CAMERA-IMU ROTATION: 2 windows refused")
    assert said[2].startswith("at 3.6 s: GYROSCOPE SCALE (tracked features): the gyroscope turns 57.9x")
    # what was said is what the end-of-run summary says, counts as of then
    state = {"startup": {"ff_rejections": st.ff_rejections, "ff_rejection_first": st.ff_rejection_first},
             "rig_check": {"gyro_scale": rc.gyro_scale}}
    assert [x.split(":")[0] for x in rig_lines(state, None)] == [x.split(":", 2)[1].strip() for x in said]


def test_a_time_offset_finding_and_a_bring_up_refused_for_the_gyro_are_said():
    st = StartupReport()
    said: list[str] = []
    bringup = SimpleNamespace(done=False, report=BringUpReport(rotation_source="tracks"))
    alerts = RigAlerts(_pipe(st, None, bringup), said.append, rig_offset_s=0.0)
    bringup.report.rejections = {"gyro_scale": 2}
    bringup.report.rejection_first = {"gyro_scale": "the gyroscope turns 57.3x as far as the camera"}
    alerts(1.0)
    assert said == []                         # two windows: not yet blamed (runtime.bringup.gyro_blamed)
    bringup.report.rejections["gyro_scale"] = 3
    alerts(2.0)
    assert said == ["at 2.0 s: GYROSCOPE SCALE (bring-up): 3 windows refused, the first: the gyroscope turns "
                    "57.3x as far as the camera. Fix the IMU's units or scale"]
    st.time_offset_findings = 1
    st.time_offset_first = "a window fits +60 ms"
    alerts(3.0)
    assert said[-1].startswith("at 3.0 s: CAMERA-IMU TIME OFFSET: 1 window fits another offset, not adopted; "
                               "the first: a window fits +60 ms")
    bringup.done = True                       # a bring-up that completed is not read again
    bringup.report = None
    alerts(4.0)
    assert len(said) == 2


def test_chain_calls_each_progress_callback():
    seen: list[tuple[str, float]] = []
    call = chain(lambda s: seen.append(("a", s)), None, lambda s: seen.append(("b", s)))
    call(1.5)
    assert seen == [("a", 1.5), ("b", 1.5)]


@pytest.mark.slow
def test_a_run_says_a_deg_per_second_gyro_while_it_runs(capsys):
    """9 s of the aggressive preset with its gyro in deg/s and no model: the tracked-feature check names it
    on stderr seconds before the recording ends, as the summary names it at the end."""
    from drivers.sim import SimConfig, SimRecording
    from runtime.config import DavioConfig
    from runtime.events import ImuSample
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
    res = run_pipeline(DegPerSecond(), None, cfg, show_progress=True)
    err = capsys.readouterr().err
    said = [x.strip() for x in err.splitlines() if "GYROSCOPE SCALE" in x]
    assert len(said) == 1 and said[0].startswith("at "), err
    assert float(said[0].split()[1]) < 8.0
    end = [x for x in rig_lines(res.pipeline.report(), None) if x.startswith("GYROSCOPE SCALE (tracked")]
    assert len(end) == 1 and "deg/s" in end[0]


def test_the_live_status_line_says_a_finding_on_its_own_line(capsys):
    from tools.commands.live import _StatusLine

    rc = RigCheckReport(gyro_scale="the gyroscope turns 57.9x as far as the tracked features see")
    pipe = _pipe(StartupReport(), rc)
    pipe.stats = SimpleNamespace(tracks_total=300, frames=3)
    pipe.published, pipe.prior = [], None
    status = _StatusLine(SimpleNamespace(pipeline=pipe, _scheduler=None), None)
    status(2.0)
    lines = capsys.readouterr().err.splitlines()
    assert lines[0] == "  at 2.0 s: GYROSCOPE SCALE (tracked features): the gyroscope turns 57.9x as far " \
        "as the tracked features see. Fix the IMU's units or scale; the filter integrates them"
    assert "100 tracks" in lines[1]            # the status line follows
    status(3.5)
    assert "GYROSCOPE" not in capsys.readouterr().err


def test_an_error_in_saying_a_finding_stops_the_alerts_not_the_run():
    rc = RigCheckReport(gyro_scale="the gyroscope turns 57.9x as far")

    def broken(line: str) -> None:
        raise BrokenPipeError("stderr closed")

    alerts = RigAlerts(_pipe(StartupReport(), rc), broken)
    alerts(1.0)
    assert alerts.error == "BrokenPipeError: stderr closed"
    assert len(alerts.said) == 1
    rc.extrinsics_rotation = "178.1 deg from the rig's: inverted"
    alerts(5.0)                                   # no longer looks, raises nothing
    assert len(alerts.said) == 1
