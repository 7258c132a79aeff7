"""The run's events (runtime.run_events): a new publisher, a reset said before what publishes after it, each
kind of rig finding once with its data time and the end-of-run summary's line, the bring-up's estimate, a
prior-map localisation; a bounded log."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from runtime.bringup import BringUpReport
from runtime.pipeline import VioPipeline
from runtime.rig_check import RigCheckReport
from runtime.rig_findings import rig_findings, rig_lines
from runtime.run_events import MAX_KEPT, RunEvents
from runtime.startup import StartupReport

T0 = 1_403_636_579_763_555_584      # a EuRoC-like sensor clock (ns)


def _s(seconds: float) -> int:
    return T0 + int(round(seconds * 1e9))


def _pipe(startup=None, rig_check=None, bringup=None, prior=None):
    pipe = SimpleNamespace(
        startup=None if startup is None else SimpleNamespace(report=startup, native=SimpleNamespace(
            last_reset_reason=None)),
        rig_check=None if rig_check is None else SimpleNamespace(report=rig_check), bringup=bringup,
        prior=prior)
    return pipe


def _events(pipe, rig_offset_s=None) -> tuple[RunEvents, list]:
    got: list = []
    ev = RunEvents(pipe, got.append, rig_offset_s)
    ev.start_ns = T0
    return ev, got


def test_each_kind_of_rig_finding_is_an_event_once_with_its_data_time_and_the_summary_s_line():
    st, rc = StartupReport(), RigCheckReport()
    events, got = _events(_pipe(st, rc))
    events.after_frame(_s(0.0))
    assert got == []
    st.ff_rejections = {"gyro_scale": 1}
    st.ff_rejection_first = {"gyro_scale": "the gyroscope turns 57.1x as far"}
    events.after_frame(_s(0.5))                  # within the data second of the last look: not read
    assert got == []
    events.after_frame(_s(1.2))
    assert [(e.kind, e.t_s, e.detail) for e in got] == [
        ("rig_finding", 1.2, {"key": "gyro_scale", "evidence": "feedforward"})]
    assert got[0].message == ("GYROSCOPE SCALE: 1 windows refused, the first: the gyroscope turns 57.1x as "
                              "far. Fix the IMU's units or scale; every filter integrates them too")
    assert got[0].t_ns == _s(1.2)
    st.ff_rejections["gyro_scale"] = 5             # the same finding again, with a new count: not said again
    st.ff_rejections["extrinsics_rotation"] = 1    # one window: not yet a finding (as the summary)
    events.after_frame(_s(2.5))
    assert len(got) == 1
    st.ff_rejections["extrinsics_rotation"] = 2
    rc.gyro_scale = "the gyroscope turns 57.9x as far as the tracked features see"
    events.after_frame(_s(3.6))
    assert [(e.detail["key"], e.detail["evidence"], e.t_s) for e in got[1:]] == [
        ("extrinsics_rotation", "feedforward", 3.6), ("gyro_scale", "tracks", 3.6)]
    assert got[1].message.startswith("CAMERA-IMU ROTATION: 2 windows refused")
    assert got[2].message.startswith("GYROSCOPE SCALE (tracked features): the gyroscope turns 57.9x")
    # the kinds said are the end-of-run summary's, which reads the whole report
    report = {"startup": {"ff_rejections": st.ff_rejections, "ff_rejection_first": st.ff_rejection_first},
              "rig_check": {"gyro_scale": rc.gyro_scale}}
    assert [x.split(":")[0] for x in rig_lines(report, None)] == [e.message.split(":")[0] for e in got]
    assert events.report() == {"counts": {"rig_finding": 3}, "not_kept": 0}
    assert events.log == got


def test_a_time_offset_finding_and_a_bring_up_refused_for_the_gyro_are_events():
    st = StartupReport()
    bringup = SimpleNamespace(done=False, report=BringUpReport(rotation_source="tracks"))
    events, got = _events(_pipe(st, None, bringup), rig_offset_s=0.0)
    bringup.report.rejections = {"gyro_scale": 2}
    bringup.report.rejection_first = {"gyro_scale": "the gyroscope turns 57.3x as far as the camera"}
    events.after_frame(_s(1.0))
    assert got == []                          # two windows: not yet blamed (runtime.bringup.gyro_blamed)
    bringup.report.rejections["gyro_scale"] = 3
    events.after_frame(_s(2.0))
    assert [(e.message, e.detail) for e in got] == [(
        "GYROSCOPE SCALE (bring-up): 3 windows refused, the first: the gyroscope turns 57.3x as far as the "
        "camera. Fix the IMU's units or scale", {"key": "gyro_scale", "evidence": "bringup"})]
    st.time_offset_findings = 1
    st.time_offset_first = "a window fits +60 ms"
    events.after_frame(_s(3.0))
    assert got[-1].message.startswith("CAMERA-IMU TIME OFFSET: 1 window fits another offset, not adopted; "
                                      "the first: a window fits +60 ms")
    assert got[-1].detail == {"key": "time_offset", "evidence": "feedforward"}
    bringup.done = True                       # a bring-up that completed is not read again
    bringup.report = None
    events.after_frame(_s(4.0))
    assert len(got) == 2


def test_each_finding_has_a_key_and_evidence_and_the_console_line_of_the_summary():
    report = {"startup": {"ff_rejections": {"gyro_scale": 2, "extrinsics_rotation": 3},
                          "ff_rejection_first": {}, "time_offset_findings": 1},
              "rig_check": {"gyro_scale": "g", "extrinsics_rotation": "r", "error": "DataError: x"},
              "bringup": {"rejections": {"gyro_scale": 4}, "rejection_first": {"gyro_scale": "b"}}}
    found = rig_findings(report, 0.01)
    assert [(f.key, f.evidence) for f in found] == [
        ("gyro_scale", "feedforward"), ("extrinsics_rotation", "feedforward"), ("gyro_scale", "tracks"),
        ("rig_check_error", "tracks"), ("extrinsics_rotation", "tracks"), ("time_offset", "feedforward"),
        ("gyro_scale", "bringup")]
    assert len({f.kind for f in found}) == len(found)          # one kind per key and evidence
    # the console lines: what was found, by which evidence, with the report's counts and first details
    lines = rig_lines(report, 0.01)
    assert [ln.split(":")[0] for ln in lines] == [
        "GYROSCOPE SCALE", "CAMERA-IMU ROTATION", "GYROSCOPE SCALE (tracked features)",
        "rig check from the tracked features ended early", "CAMERA-IMU ROTATION (tracked features)",
        "CAMERA-IMU TIME OFFSET", "GYROSCOPE SCALE (bring-up)"]
    assert "2 windows refused" in lines[0] and "3 windows refused" in lines[1]
    assert lines[2].startswith("GYROSCOPE SCALE (tracked features): g.") and lines[3].endswith("DataError: x")
    assert lines[4].startswith("CAMERA-IMU ROTATION (tracked features): r.")
    assert "1 window fits another offset, not adopted" in lines[5]
    assert lines[6].startswith("GYROSCOPE SCALE (bring-up): 4 windows refused, the first: b.")
    # a rotation a few degrees off, from the tracked features: its own key and line
    suspect = rig_findings({"rig_check": {"extrinsics_suspect": "s"}}, None)
    assert [(f.key, f.evidence) for f in suspect] == [("extrinsics_suspect", "tracks")]
    assert suspect[0].line.startswith("CAMERA-IMU ROTATION? (tracked features): s. A rotation off by degrees")
    assert "calib_extrinsics = true" in suspect[0].line
    # said once, whatever a later judgement's text (the kind is the line's head)
    again = rig_findings({"rig_check": {"extrinsics_suspect": "another span count and angle"}}, None)
    assert suspect[0].kind == again[0].kind == "CAMERA-IMU ROTATION? (tracked features)"


def _published(t_s: float, segment: int, source: str):
    return SimpleNamespace(t_ns=_s(t_s), segment=segment, source=source)


def test_a_new_publisher_is_an_event_and_a_reset_is_said_before_what_publishes_after_it():
    st = StartupReport()
    pipe = _pipe(st)
    events, got = _events(pipe)
    events.on_published([_published(2.0, 0, "native:static"), _published(2.005, 0, "native:static")])
    events.on_published([_published(2.01, 0, "native:static")])
    events.after_frame(_s(2.05))
    assert [(e.kind, e.t_s, e.message, e.detail) for e in got] == [
        ("publishing", 2.0, "publishing metric poses (native:static)",
         {"source": "native:static", "segment": 0})]
    # the filter diverges and resets: said at the next look, with the filter's reason
    st.restarts_after_divergence = 1
    pipe.startup.native.last_reset_reason = "no update for 3.0 s"
    events.after_frame(_s(7.3))
    assert (got[-1].kind, got[-1].t_s, got[-1].detail) == (
        "reset", 7.3, {"segment": 0, "reason": "no update for 3.0 s", "resets": 1})
    assert "diverged (no update for 3.0 s) and was reset" in got[-1].message
    events.on_published([_published(8.1, 1, "feedforward")])
    assert (got[-1].kind, got[-1].message, got[-1].detail) == (
        "publishing", "publishing metric poses again (feedforward), segment 1",
        {"source": "feedforward", "segment": 1})
    # a reset not yet looked for when the next publisher's poses come is said first
    st.restarts_after_divergence = 2
    events.on_published([_published(12.0, 2, "native:dynamic")])
    assert [e.kind for e in got[-2:]] == ["reset", "publishing"]
    assert got[-2].detail["segment"] == 1 and got[-2].t_ns == got[-1].t_ns == _s(12.0)
    assert events.report()["counts"] == {"publishing": 3, "reset": 2}


def test_the_bring_up_s_estimate_and_a_prior_map_localisation_are_events():
    prior = SimpleNamespace(localized_at_ns={}, source="runs/rec1")
    events, got = _events(_pipe(StartupReport(), prior=prior))
    rep = BringUpReport(windows_used=4, fit_rms_deg=0.31, R_IC=np.eye(3).tolist())
    events.calibration_estimated(_s(6.5), rep)
    assert (got[0].kind, got[0].t_s, got[0].detail) == (
        "calibration_estimated", 6.5, {"windows_used": 4, "R_IC": np.eye(3).tolist()})
    assert got[0].message.startswith("calibration bring-up done: the camera-IMU rotation estimated from 4 "
                                     "windows (fit 0.31 deg rms)")
    events.after_frame(_s(9.0))
    assert len(got) == 1
    prior.localized_at_ns[0] = _s(9.2)
    events.after_frame(_s(9.3))
    prior.localized_at_ns[2] = _s(20.0)
    events.after_frame(_s(20.1))
    events.after_frame(_s(20.2))
    assert [(e.kind, e.t_s, e.detail) for e in got[1:]] == [
        ("prior_localised", 9.3, {"segment": 0, "source": "runs/rec1"}),
        ("prior_localised", 20.1, {"segment": 2, "source": "runs/rec1"})]
    assert got[2].message == "localised in the prior map runs/rec1 (segment 2): poses now also in its frame"


class _Localizer:
    """A PriorMapLocalizer's interface as PriorFrame uses it: every view it is given localises its segment."""

    def __init__(self) -> None:
        self.T: dict[int, np.ndarray] = {}

    def add_view(self, view, segment: int = 0) -> bool:
        self.T[int(segment)] = np.eye(4)
        return True

    def segments(self) -> list[int]:
        return sorted(self.T)

    def T_PN(self, segment: int = 0):
        return self.T.get(int(segment))

    def segment_versions(self) -> dict[int, int]:
        return {seg: 1 for seg in self.T}

    def state(self, segment: int):
        return 1, self.T.get(int(segment)), 0


def _submap(segment: int) -> SimpleNamespace:
    return SimpleNamespace(index=7, T_MS=np.eye(4), view=("features", "view"), segment=segment)


def test_localisations_taken_up_after_the_last_frame_or_found_by_the_mapping_after_the_end_are_said():
    from runtime.graph.prior_frame import PriorFrame

    prior = PriorFrame(_Localizer(), "runs/rec1")
    events, got = _events(_pipe(StartupReport(), prior=prior))
    prior.on_submap(_submap(0))
    prior.update(_s(3.0))                       # taken up by the tracking thread while running
    events.after_frame(_s(3.1))
    prior.on_submap(_submap(2))
    prior.update(_s(9.95))                      # a commit taken up after the last frame
    events.data_ended(_s(10.0))
    prior.on_submap(_submap(1))                 # the mapping after the data ended: never taken up
    events.after_mapping(_s(9.98))              # the last IMU time, before the data's end
    assert [(e.kind, e.t_s, e.detail) for e in got] == [
        ("prior_localised", 3.1, {"segment": 0, "source": "runs/rec1"}),
        ("prior_localised", 10.0, {"segment": 2, "source": "runs/rec1"}),
        ("prior_localised", 10.0, {"segment": 1, "source": "runs/rec1", "after_end": True})]
    assert got[2].message == ("localised in the prior map runs/rec1 (segment 1): the final trajectory is "
                              "also in its frame (found by the mapping after the data ended)")
    assert prior.localized_at_ns.keys() == {0, 2}     # saying it took nothing up
    events.after_mapping(_s(10.0))              # nothing new: nothing said
    assert len(got) == 3


def test_the_pipeline_says_what_its_end_of_data_mapping_localised():
    from calib.io import euroc_rig
    from runtime.config import DavioConfig
    from runtime.graph.prior_frame import PriorFrame

    got: list = []
    pipe = VioPipeline(euroc_rig(), None, DavioConfig(), on_event=got.append)
    pipe._last_t = _s(12.0)
    pipe.prior = PriorFrame(_Localizer(), "runs/rec1")
    queued = ["window"]
    pipe.map_queue = SimpleNamespace(pop=lambda: queued.pop() if queued else None)
    # the last window's submap localises segment 0 (the mapping job hands it to the prior frame)
    pipe._mapping_job = lambda window: (lambda: pipe.prior.on_submap(_submap(0)))
    assert pipe.finish_mapping() == 1
    assert [(e.kind, e.t_ns, e.detail["after_end"]) for e in got] == [("prior_localised", _s(12.0), True)]
    assert pipe.finish_mapping() == 0 and len(got) == 1


def test_the_log_is_bounded_and_counts_what_it_did_not_keep():
    st = StartupReport()
    events, got = _events(_pipe(st))
    for k in range(MAX_KEPT + 5):     # a run that resets again and again
        events.on_published([_published(float(k), k, "native:static")])
    assert len(got) == MAX_KEPT + 5 and len(events.log) == MAX_KEPT
    assert events.report() == {"counts": {"publishing": MAX_KEPT + 5}, "not_kept": 5}
    assert got[-1].to_json() == {"t_ns": _s(MAX_KEPT + 4.0), "t_s": MAX_KEPT + 4.0, "kind": "publishing",
                                 "message": f"publishing metric poses again (native:static), segment "
                                            f"{MAX_KEPT + 4}", "source": "native:static",
                                 "segment": MAX_KEPT + 4}


def test_features_lost_is_said_after_a_second_with_too_few_and_features_back_when_they_return():
    from runtime.run_events import FEATURES_LOST_S, FEW_FEATURES

    events, got = _events(_pipe(StartupReport()))
    events.after_frame(_s(0.0), 150)
    events.after_frame(_s(0.05), 0)                       # one dark frame: not news
    events.after_frame(_s(0.10), 150)
    for k in range(0, 21):                                # 1.0 s of frames with one feature too few
        events.after_frame(_s(1.0 + 0.05 * k), FEW_FEATURES - 1)
        assert len(got) == (1 if 0.05 * k >= FEATURES_LOST_S - 1e-9 else 0)
    assert (got[0].kind, got[0].t_s, got[0].detail) == (
        "features_lost", 2.0, {"since_t_ns": _s(1.0), "features": FEW_FEATURES - 1})
    events.after_frame(_s(2.5), 3)                        # still lost: said once
    events.after_frame(_s(3.2), FEW_FEATURES)
    assert [(e.kind, e.t_s, e.detail) for e in got[1:]] == [
        ("features_back", 3.2, {"lost_s": 2.2, "features": FEW_FEATURES})]
    assert got[1].message == f"features tracked again ({FEW_FEATURES}) after 2.2 s"
    events.after_frame(_s(3.3), 0)                        # a new run of few features starts afresh
    events.after_frame(_s(4.2), 0)
    assert len(got) == 2
    events.after_frame(_s(4.3), 0)
    assert got[-1].kind == "features_lost" and got[-1].detail["since_t_ns"] == _s(3.3)


def test_images_dropped_live_are_said_at_once_then_at_most_every_ten_data_seconds():
    from runtime.run_events import DROPS_EVERY_S

    events, got = _events(_pipe(StartupReport()))
    events.frames_dropped(0, _s(1.0))
    assert got == []
    events.frames_dropped(2, _s(1.0))
    events.frames_dropped(5, _s(2.0))                     # within ten seconds: counted, not said
    events.frames_dropped(9, _s(1.0 + DROPS_EVERY_S))
    events.frames_dropped(9, _s(30.0))                    # nothing new
    assert [(e.t_s, e.detail) for e in got] == [(1.0, {"dropped": 2, "total": 2}),
                                                (11.0, {"dropped": 7, "total": 9})]
    assert got[0].message.startswith("tracking falls behind the camera: 2 images dropped, 2 in all")
    assert got[1].message.startswith("tracking falls behind the camera: 7 images dropped since the last such "
                                     "event, 9 in all")


def _head_replayed(edit) -> tuple[list, object, list]:
    """The real EuRoC V1_01 head's first 3.5 s through DAVIO (native only) with `edit(k_frame, rel_s, event)`
    giving the events to replay in place of each one (k_frame: the frame's index, None for IMU samples);
    returns (the run events, the run, the frames' stamps)."""
    from conftest import shared_path

    from drivers.euroc import EurocDriver
    from runtime.config import DavioConfig
    from runtime.events import Frame
    from tools.run_session import run_pipeline

    drv = EurocDriver(shared_path("euroc", "V1_01_easy_head"))
    t0 = next(iter(drv.events())).t_ns
    frames = [ev.t_ns for ev in drv.events() if isinstance(ev, Frame)]

    class Edited:
        rig = drv.rig

        def events(self):
            k = 0
            for ev in drv.events():
                is_frame = isinstance(ev, Frame)
                yield from edit(k if is_frame else None, (ev.t_ns - t0) / 1e9, ev)
                k += is_frame

    got: list = []
    res = run_pipeline(Edited(), None, DavioConfig(), show_progress=False, seconds=3.5, on_event=got.append)
    return got, res, frames


def test_a_covered_camera_on_the_real_euroc_head_is_said_and_its_return_too():
    """Frames 30-59 (1.5-3.0 s) of V1_01's head made black: features_lost 1 s into the dark, features_back
    on the first frame with an image, each once."""
    from runtime.events import Frame

    def covered(k, rel_s, ev):
        black = k is not None and 30 <= k < 60
        return [Frame(ev.t_ns, np.zeros_like(ev.image), ev.camera_id) if black else ev]

    got, res, frames = _head_replayed(covered)
    lost = [e for e in got if e.kind.startswith("features")]
    assert [(e.kind, e.t_ns) for e in lost] == [("features_lost", frames[50]), ("features_back", frames[60])]
    assert lost[0].detail == {"since_t_ns": frames[30], "features": 0} and lost[1].detail["features"] > 100
    assert res.pipeline.report()["events"]["counts"]["features_lost"] == 1


def test_a_publisher_whose_first_poses_diverge_is_said_between_the_two_resets_each_with_its_segment():
    """Segment 0 publishes and resets; segment 1's first batch diverges within the same call (the start-up
    publishes, then restarts): reset 1 (segment 0), publishing (segment 1), reset 2 (segment 1)."""
    st = StartupReport()
    pipe = _pipe(st)
    events, got = _events(pipe)
    events.on_published([_published(2.0, 0, "native:static")])
    st.restarts_after_divergence = 2                      # both resets happened before we look
    pipe.startup.native.last_reset_reason = "chi2 rejected 90% of features"
    events.on_published([_published(6.0, 1, "feedforward"), _published(6.05, 1, "feedforward")])
    said = [(e.kind, e.detail.get("segment"), e.detail.get("resets"), e.detail.get("reason")) for e in got]
    assert said == [
        ("publishing", 0, None, None), ("reset", 0, 1, "unknown"), ("publishing", 1, None, None),
        ("reset", 1, 2, "chi2 rejected 90% of features")]
    assert [e.t_ns for e in got[1:]] == [_s(6.0), _s(6.0), _s(6.05)]
    events.on_published([_published(9.0, 2, "native:dynamic")])     # no reset left to say
    assert [e.kind for e in got[4:]] == ["publishing"]


def test_a_reset_found_on_an_imu_sample_is_said_at_that_sample():
    st = StartupReport()
    pipe = _pipe(st)
    events, got = _events(pipe)
    events.on_published([_published(2.0, 0, "native:static")])
    events.after_imu(_s(3.0))
    st.restarts_after_divergence = 1
    events.after_imu(_s(3.005))
    events.after_frame(_s(3.05), 100)
    assert [(e.kind, e.t_s) for e in got] == [("publishing", 2.0), ("reset", 3.005)]


def test_held_events_wait_for_flush_and_keep_their_order():
    events, got = _events(_pipe(StartupReport()))
    events.hold = True
    events.on_published([_published(2.0, 0, "native:static")])
    events.frames_dropped(3, _s(2.0))
    assert got == [] and [e.kind for e in events.pending] == ["publishing", "falling_behind"]
    assert len(events.log) == 2                                     # the log has them at once
    events.flush()
    assert [e.kind for e in got] == ["publishing", "falling_behind"] and events.pending == []


def test_a_failing_look_for_rig_findings_is_counted_not_raised_into_the_run(monkeypatch):
    import runtime.run_events

    pipe = _pipe(StartupReport())

    def broken(pipeline):
        raise KeyError("gyro_scale")

    monkeypatch.setattr(runtime.run_events, "rig_state", broken)
    events, got = _events(pipe)
    events.after_frame(_s(1.0), 100)
    events.after_frame(_s(2.5), 100)
    assert got == [] and events.report()["look_errors"] == 2
    assert events.report()["look_error_first"] == "KeyError: 'gyro_scale'"


def test_images_dropped_after_the_last_event_are_said_when_the_data_ends():
    events, got = _events(_pipe(StartupReport()))
    events.frames_dropped(1, _s(1.0))
    events.frames_dropped(4, _s(3.0))                     # within ten seconds: held back
    events.frames_dropped(4, _s(5.0), final=True)
    assert [(e.t_s, e.detail) for e in got] == [(1.0, {"dropped": 1, "total": 1}),
                                                (5.0, {"dropped": 3, "total": 4})]


def test_imu_gaps_are_said_at_once_then_gathered_for_ten_data_seconds_and_the_rest_at_the_end():
    events, got = _events(_pipe(StartupReport()))
    events.imu_gap(_s(1.0), 0.21, 0)
    events.imu_gap(_s(2.0), 0.08, 12)
    events.imu_gap(_s(5.0), 0.30, 40)                     # within ten seconds of the first: gathered
    assert [(e.t_s, e.detail) for e in got] == [
        (1.0, {"gaps": 1, "longest_s": 0.21, "lost": 0, "total": 1})]
    assert got[0].message == "IMU stream: a 0.210 s gap; a running filter propagates across it"
    events.imu_gap(_s(11.0), 0.06, 0)
    assert (got[-1].t_s, got[-1].detail) == (11.0, {"gaps": 3, "longest_s": 0.3, "lost": 52, "total": 4})
    assert got[-1].message == ("IMU stream: 3 gaps since the last such event, the longest 0.300 s (52 "
                               "samples lost by the driver); a running filter propagates across it")
    events.imu_gap(_s(12.0), 0.07, 0)
    events.data_ended(_s(13.0))
    assert (got[-1].t_s, got[-1].detail) == (13.0, {"gaps": 1, "longest_s": 0.07, "lost": 0, "total": 5})
    events.data_ended(_s(14.0))                           # nothing left
    assert len(got) == 3


def test_an_imu_gap_and_samples_a_driver_lost_on_the_real_euroc_head_are_said_as_the_filter_counts_them():
    """V1_01's head with its IMU samples of 1.0-1.3 s removed and one sample at 2.5 s flagged as following
    7 lost ones: two imu_gap events (the second gathered, said at the end), as many gaps as the filter
    counts."""
    from runtime.events import ImuSample

    flagged: list = []

    def flaky(k, rel_s, ev):
        if k is not None:
            return [ev]
        if 1.0 <= rel_s < 1.3:
            return []
        if rel_s >= 2.5 and not flagged:
            flagged.append(ev)
            return [ImuSample(ev.t_ns, ev.gyro, ev.accel, lost_before=7)]
        return [ev]

    got, res, _ = _head_replayed(flaky)
    gaps = [e for e in got if e.kind == "imu_gap"]
    assert [e.detail["gaps"] for e in gaps] == [1, 1]
    assert gaps[0].detail["longest_s"] == pytest.approx(0.3, abs=0.01)
    assert gaps[0].t_s == pytest.approx(1.3, abs=0.01) and gaps[1].detail["lost"] == 7
    assert gaps[1].t_s == pytest.approx(3.5, abs=0.06)          # gathered within ten seconds: said at the end
    assert gaps[-1].detail["total"] == res.pipeline.report()["filter"]["imu_gaps"] == 2


def test_imu_gaps_are_measured_between_the_samples_the_filter_keeps():
    """A stamp 0.5 s back and 0.2 s of samples beyond any IMU's range, on the real EuRoC head: the first is
    no gap (the filter drops it; the next sample is measured from the last kept), the second is one, as the
    filter counts them."""
    from runtime.events import ImuSample

    back: list = []

    def corrupt(k, rel_s, ev):
        if k is not None:
            return [ev]
        out = []
        if rel_s >= 2.0 and not back:
            back.append(ev)
            out.append(ImuSample(ev.t_ns - 500_000_000, ev.gyro, ev.accel))
        out.append(ImuSample(ev.t_ns, np.full(3, 1e4), ev.accel) if 2.6 <= rel_s < 2.8 else ev)
        return out

    got, res, _ = _head_replayed(corrupt)
    gaps = [e for e in got if e.kind == "imu_gap"]
    assert len(gaps) == 1 and gaps[0].detail["longest_s"] == pytest.approx(0.2, abs=0.01)
    assert gaps[0].t_s == pytest.approx(2.8, abs=0.01)
    rep = res.pipeline.report()
    assert rep["filter"]["imu_gaps"] == 1 and rep["filter"]["imu_out_of_order"] == 1
    assert rep["tracking"]["imu_out_of_range"] == 40


def test_the_pipeline_says_a_reset_found_on_an_imu_sample_at_that_sample():
    from conftest import shared_path

    from drivers.euroc import EurocDriver
    from runtime.events import ImuSample

    drv = EurocDriver(shared_path("euroc", "V1_01_easy_head"))
    got: list = []
    pipe = VioPipeline(drv.rig, on_event=got.append)
    imu = [ev for _, ev in zip(range(400), drv.events(), strict=False) if isinstance(ev, ImuSample)][:3]
    pipe.on_imu(imu[0])
    pipe.startup.report.restarts_after_divergence = 1      # as a divergence in that step leaves it
    pipe.on_imu(imu[1])
    assert [(e.kind, e.t_ns, e.detail["resets"]) for e in got] == [("reset", imu[1].t_ns, 1)]


def test_stamps_that_go_back_are_said_once_until_they_pass_the_newest() -> None:
    """A clock that jumped back dropped 3 s of data counted only as out-of-order samples; the only event was
    features_lost ("the camera sees nothing to track")."""
    from types import SimpleNamespace as S

    events, got = _events(_pipe(StartupReport()))
    z = np.zeros(3)
    for k in range(40):                                    # 2 s at 20 Hz
        events.imu_sample(S(t_ns=_s(0.05 * k), gyro=z, accel=z))
    for k in range(10):                                    # restamped 1.5 s back, then a late repeat
        events.imu_sample(S(t_ns=_s(0.4 + 0.05 * k), gyro=z, accel=z))
    events.imu_sample(S(t_ns=_s(1.9), gyro=z, accel=z))   # 0.05 s back: a late sample, not a clock
    back = [e for e in got if e.kind == "stamps_back"]
    assert len(back) == 1 and back[0].detail == {"back_s": 1.55, "newest_t_ns": _s(1.95)}
    assert back[0].t_s == pytest.approx(1.95) and "went back 1.55 s" in back[0].message
    events.imu_sample(S(t_ns=_s(2.0), gyro=z, accel=z))   # past the newest: a later jump is said again
    events.imu_sample(S(t_ns=_s(0.5), gyro=z, accel=z))
    assert [e.kind for e in got].count("stamps_back") == 2


def test_a_model_failure_is_said_on_one_line_of_bounded_length() -> None:
    """ONNX Runtime's exceptions run over several lines of C++ text: the event is one line."""
    events, got = _events(_pipe(StartupReport()))
    events.model_failures(_s(1.0), 1, "ModelError: x.onnx: inference failed (Fail: [ONNXRuntimeError]\n"
                          + "  at onnxruntime::InferenceSession::Run " * 40 + "\n)")
    [said] = [e for e in got if e.kind == "model_error"]
    assert "\n" not in said.message and len(said.detail["first"]) == 300
    assert said.detail["first"].startswith("ModelError: x.onnx: inference failed (Fail: [ONNXRuntimeError]")
    assert said.detail["first"].endswith("...") and (said.detail["failed"], said.detail["total"]) == (1, 1)
