"""The start-up manager's re-solves of a refused window over a longer span (runtime/startup.py with
runtime/ffinit/extension.py): which frames, how often, when they stop, and what is counted."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from startup_fakes import RecordingFilter
from startup_fakes import stream as _stream

from runtime.events import Frame, ImuSample
from runtime.msckf.init_common import InitResult
from runtime.startup import StartupConfig, StartupManager

MS = 1_000_000
WINDOW = [0, 200 * MS, 400 * MS, 600 * MS, 800 * MS]


def _manager(cfg: StartupConfig | None = None) -> tuple[StartupManager, list]:
    m = StartupManager(lambda native: RecordingFilter(), cfg or StartupConfig())
    return m, [e for e in _stream(4.0)]


def _feed(m: StartupManager, events: list, until_ns: int) -> list:
    """Feed the events up to until_ns (tracks: 3 ids at the frame's stamp); returns the rest."""
    while events and events[0][1] <= until_ns:
        kind, t = events.pop(0)
        if kind == "imu":
            m.on_imu(ImuSample(t, np.zeros(3), np.array([0, 0, 9.81])))
        else:
            m.on_tracks(t, np.arange(3) + t, np.zeros((3, 2)), Frame(t, np.zeros((4, 4), np.uint8)))
    return events


def _refusal(extendable: bool = True) -> SimpleNamespace:
    seed = SimpleNamespace(t_cam_ns=np.array(WINDOW, np.int64), last_ns=WINDOW[-1])
    return SimpleNamespace(reason="scale_unobservable", seed=seed if extendable else None)


def test_a_refused_window_is_re_solved_with_the_newer_frames_one_spacing_at_a_time_until_it_expires():
    m, ev = _manager()
    ev = _feed(m, ev, 1300 * MS)          # the model answered 0.5 s after the window's last image
    assert m.extension() is None          # nothing refused yet
    m.on_feedforward(_refusal())
    assert m.report.ff_rejections == {"scale_unobservable": 1} and m.extension_pending()
    seed, stamps = m.extension()
    assert stamps == WINDOW + [1100 * MS, 1300 * MS]   # spaced 0.2 s back from the newest frame
    tracks = m.tracks_at(stamps)
    assert [t for t, _, _ in tracks] == stamps and np.array_equal(tracks[-1][1], np.arange(3) + 1300 * MS)
    m.note_extension(stamps)
    ev = _feed(m, ev, 1450 * MS)
    assert m.extension() is None          # not a spacing after the last re-solve yet
    m.on_feedforward(_refusal(), extension=True)
    ev = _feed(m, ev, 1500 * MS)
    _, stamps = m.extension()
    assert stamps == WINDOW + [1100 * MS, 1300 * MS, 1500 * MS]
    m.note_extension(stamps)
    assert m.report.ff_extensions == 2 and m.report.ff_extension_rejections == {"scale_unobservable": 1}
    ev = _feed(m, ev, 1800 * MS)          # exactly extend_refused_s after the window: still alive
    assert m.extension() is not None
    _feed(m, ev, 1850 * MS)
    assert m.extension() is None and not m.extension_pending()
    assert m.report.ff_extension_expired == 1


def test_an_accepted_re_solve_starts_a_candidate_and_a_final_refusal_ends_the_re_solves():
    m, ev = _manager()
    ev = _feed(m, ev, 1300 * MS)
    m.on_feedforward(_refusal())
    m.on_feedforward(_refusal(extendable=False), extension=True)    # e.g. extension_pnp_failed
    assert not m.extension_pending() and m.extension() is None
    m.on_feedforward(_refusal())                                    # a later window, refused again
    m.note_extension(m.extension()[1])
    ev = _feed(m, ev, 1400 * MS)
    state = InitResult(1300 * MS, np.eye(3), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), None,
                       "feedforward")
    m.on_feedforward(state, extension=True)
    assert m.report.ff_extension_accepted == 1 and m.report.ff_accepted == 0   # model windows only
    assert m.report.candidates_started == 1 and not m.extension_pending()


def test_re_solves_are_off_with_extend_refused_s_zero_and_a_missing_track_set_gives_none():
    m, ev = _manager(StartupConfig(extend_refused_s=0.0))
    _feed(m, ev, 1300 * MS)
    m.on_feedforward(_refusal())
    assert not m.extension_pending() and m.extension() is None
    m2, ev2 = _manager(StartupConfig())
    _feed(m2, ev2, 1300 * MS)
    assert m2.tracks_at([1300 * MS, 1325 * MS]) is None             # no frame at 1.325 s
    m2.on_feedforward(_refusal())
    m2.end_extension("extension_tracks_lost")                       # what the pipeline does then
    assert not m2.extension_pending() and m2.report.ff_extension_rejections == {"extension_tracks_lost": 1}


def test_imu_lost_inside_the_span_ends_the_re_solves_once_without_counting_a_lost_model_window():
    m, ev = _manager()
    out = []
    for kind, t in ev:
        if t > 1300 * MS:
            break
        if kind == "imu":
            lost = 3 if t == 1_005_000_000 else 0      # after the window, inside the re-solve's span
            m.on_imu(ImuSample(t, np.zeros(3), np.array([0, 0, 9.81]), lost_before=lost))
        else:
            m.on_tracks(t, np.arange(3) + t, np.zeros((3, 2)), Frame(t, np.zeros((4, 4), np.uint8)))
        out.append(t)
    m.on_feedforward(_refusal())
    _, stamps = m.extension()
    assert m.extension_imu(WINDOW) is not None                      # the window itself is intact
    assert m.extension_imu(stamps) is None and not m.extension_pending()
    assert m.report.ff_extension_rejections == {"extension_imu_lost": 1}
    assert m.report.ff_windows_imu_lost == 0


def test_a_refusal_that_arrives_after_another_filter_published_keeps_no_seed():
    m = StartupManager(lambda native: RecordingFilter(native_init_at_ns=1000 * MS), StartupConfig())
    _feed(m, list(_stream(4.0)), 1300 * MS)
    assert m.published
    m.on_feedforward(_refusal(), extension=True)
    assert not m.extension_pending() and m.extension() is None


def test_the_report_keeps_each_rejection_reasons_first_detail():
    from runtime.ffinit.window import Rejection

    m, _ = _manager()
    m.on_feedforward(Rejection("gyro_scale", "the gyroscope turns 57.3x as fast"))
    m.on_feedforward(Rejection("gyro_scale", "the gyroscope turns 60.1x as fast"))
    m.on_feedforward(Rejection("small_baseline", "baseline 0.01"))
    m.on_feedforward(Rejection("gyro_bias_step", "re-solve"), extension=True)    # a re-solve's: not kept
    assert m.report.ff_rejections == {"gyro_scale": 2, "small_baseline": 1}
    assert m.report.ff_rejection_first == {"gyro_scale": "the gyroscope turns 57.3x as fast",
                                           "small_baseline": "baseline 0.01"}
