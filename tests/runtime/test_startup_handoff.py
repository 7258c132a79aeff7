"""Buffered-replay handoff (paper Sec. IV-C): a caught-up candidate is selected after five live
states, without losing or repeating a measurement; slow candidates are abandoned; limits hold."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from startup_fakes import RecordingFilter
from startup_fakes import stream as _stream

from runtime.events import Frame, ImuSample
from runtime.msckf.init_common import InitResult
from runtime.startup import StartupConfig, StartupManager


def _run(manager: StartupManager, events, ff_at_ns: int | None, ff_state_ns: int):
    published = []
    done = False
    for kind, t in events:
        if kind == "imu":
            published += manager.on_imu(ImuSample(t, np.zeros(3), np.array([0, 0, 9.81])))
        else:
            published += manager.on_tracks(t, np.arange(3), np.zeros((3, 2)),
                                           Frame(t, np.zeros((4, 4), np.uint8)))
        if ff_at_ns is not None and not done and t >= ff_at_ns:
            manager.on_feedforward(InitResult(ff_state_ns, np.eye(3), np.zeros(3), np.zeros(3),
                                              np.zeros(3), np.zeros(3), None, "feedforward"))
            done = True
    return published



def _never_replaying() -> StartupConfig:
    """A configuration whose candidates never replay (to watch the window and candidate bookkeeping alone):
    replay_batch = 0 is refused as a setting, so it is set after the checks."""
    cfg = StartupConfig()
    cfg.replay_batch = 0
    return cfg

def test_candidate_replays_every_measurement_once_and_is_selected_after_five_live_states():
    filters = []

    def make(native):
        f = RecordingFilter()
        filters.append(f)
        return f

    m = StartupManager(make, StartupConfig(replay_batch=5))
    events = _stream(6.0)
    state_t = 1_000_000_000
    pub = _run(m, events, ff_at_ns=2_000_000_000, ff_state_ns=state_t)
    assert m.report.published_by == "feedforward" and m.report.candidates_selected == 1
    cand = filters[1]
    # every measurement from the last 50 ms before the state time on, in order, exactly once
    start = next(i for i, (k, t) in enumerate(events) if k == "imu" and t >= state_t - 50_000_000)
    expected = [("imu" if k == "imu" else "tracks", t) for k, t in events[start:]]
    assert cand.fed == expected
    # the first published state is live (within 0.15 s of the newest frame when published)
    first = pub[0]
    assert first.source == "feedforward"
    assert all(p.t_cam_ns > state_t for p in pub)
    ts = [p.t_cam_ns for p in pub]
    assert ts == sorted(set(ts))  # no repeated or out-of-order states


def test_replayed_states_within_catch_up_count_towards_selection():
    """Paper Sec. IV-C: selected once five consecutive states lie within 0.15 s of the live stream.
    Delivered at the 2.00 s frame for a 1.50 s state, a fast replay produces the states of the frames
    1.85, 1.90, 1.95 and 2.00 s within 0.15 s of the newest frame (2.00 s); the live 2.05 s frame is the
    fifth, so the candidate publishes at 2.05 s, and what was still buffered is fed, once, in order."""
    filters = []

    def make(native):
        f = RecordingFilter()
        filters.append(f)
        return f

    m = StartupManager(make, StartupConfig(replay_batch=60))
    events = _stream(3.0)
    pub = _run(m, events, ff_at_ns=2_000_000_000, ff_state_ns=1_500_000_000)
    assert m.report.published_by == "feedforward"
    assert pub[0].t_cam_ns == 2_050_000_000
    start = next(i for i, (k, t) in enumerate(events) if k == "imu" and t >= 1_450_000_000)
    assert filters[1].fed == [("imu" if k == "imu" else "tracks", t) for k, t in events[start:]]


def test_slow_candidate_is_abandoned_after_three_seconds():
    m = StartupManager(lambda native: RecordingFilter(), StartupConfig(replay_batch=1))
    _run(m, _stream(6.0), ff_at_ns=2_000_000_000, ff_state_ns=200_000_000)
    assert m.report.candidates_abandoned == 1 and m.report.published_by is None


def test_native_initializer_publishes_when_ready_first():
    made = []

    def make(native):
        f = RecordingFilter(native_init_at_ns=1_000_000_000 if not made else None)
        made.append(f)
        return f

    m = StartupManager(make)
    pub = _run(m, _stream(3.0), ff_at_ns=None, ff_state_ns=0)
    assert m.report.published_by == "native:static"
    assert pub and pub[0].t_cam_ns > 1_000_000_000


def test_state_older_than_the_buffer_is_refused():
    m = StartupManager(lambda native: RecordingFilter(), StartupConfig(buffer_s=1.0))
    _run(m, _stream(4.0), ff_at_ns=3_500_000_000, ff_state_ns=1_000_000_000)
    assert m.report.candidates_refused_buffer == 1 and m.report.candidates_started == 0


def test_at_most_five_candidates_and_window_selection():
    m = StartupManager(lambda native: RecordingFilter(), _never_replaying())
    for kind, t in _stream(2.0):
        if kind == "imu":
            m.on_imu(ImuSample(t, np.zeros(3), np.zeros(3)))
        else:
            m.on_tracks(t, np.arange(1), np.zeros((1, 2)), Frame(t, np.zeros((2, 2), np.uint8)))
    win = m.window()
    assert [f.t_ns for f in win] == [1_200_000_000, 1_400_000_000, 1_600_000_000, 1_800_000_000,
                                     2_000_000_000]
    assert m.imu_for(win) is not None
    for _ in range(7):
        m.on_feedforward(InitResult(1_900_000_000, np.eye(3), np.zeros(3), np.zeros(3), np.zeros(3),
                                    np.zeros(3), None, "feedforward"))
    assert m.report.candidates_started == 5 and m.window() is None


def test_an_instant_model_is_offered_one_window_per_spacing_not_one_per_event():
    """With a model that answers at once (--model-latency 0), asking for a window after every event would
    re-solve nearly the same five images hundreds of times: requests are at least one spacing apart."""
    m = StartupManager(lambda native: RecordingFilter(), StartupConfig())
    ends = []
    for kind, t in _stream(4.0):
        if kind == "imu":
            m.on_imu(ImuSample(t, np.zeros(3), np.array([0, 0, 9.81])))
        else:
            m.on_tracks(t, np.arange(3), np.zeros((3, 2)), Frame(t, np.zeros((4, 4), np.uint8)))
        frames = m.window()               # asked after every event, as the scheduler does
        if frames is not None:
            m.note_request(frames)
            ends.append(frames[-1].t_ns)
            m.on_feedforward(SimpleNamespace(reason="test_rejection"))   # answered at once
    spacing = StartupConfig().window_spacing_s * 1e9
    assert len(ends) >= 15 and np.all(np.diff(ends) >= 0.999 * spacing)
    assert len(ends) <= 4.0 / StartupConfig().window_spacing_s
    assert m.report.ff_requests == len(ends)


def _feed(m: StartupManager, keep_imu=lambda t: True, lost=lambda t: 0) -> dict:
    """Three seconds of the synthetic stream into `m` (IMU samples `keep_imu` keeps, flagged with `lost`);
    the frames by stamp."""
    frames = {}
    for kind, t in _stream(3.0):
        if kind == "imu":
            if keep_imu(t):
                m.on_imu(ImuSample(t, np.zeros(3), np.array([0, 0, 9.81]), lost_before=lost(t)))
        else:
            frames[t] = Frame(t, np.zeros((4, 4), np.uint8))
            m.on_tracks(t, np.zeros(0, np.int64), np.zeros((0, 2)), frames[t])
    return frames


def test_feedforward_windows_across_lost_imu_samples_are_not_solved():
    """A live driver flags samples lost to its IMU queue's overflow (ImuSample.lost_before): a start-up
    window spanning the loss gets no IMU (preintegration across it would be wrong), counted once; the
    next window after the loss is solved as usual."""
    m = StartupManager(lambda native: RecordingFilter(), StartupConfig())
    by_t = _feed(m, lost=lambda t: 4 if t == 1_505_000_000 else 0)
    spanning = [by_t[t] for t in (1_000_000_000, 1_200_000_000, 1_400_000_000, 1_600_000_000, 1_800_000_000)]
    after = [by_t[t] for t in (1_600_000_000, 1_800_000_000, 2_000_000_000, 2_200_000_000, 2_400_000_000)]
    before = [by_t[t] for t in (200_000_000, 400_000_000, 600_000_000, 800_000_000, 1_000_000_000)]
    assert m.imu_for(spanning) is None and m.imu_for(spanning) is None
    assert m.report.ff_windows_imu_lost == 1
    t, w, a = m.imu_for(after)
    assert t[0] <= 1_600_000_000 and t[-1] >= 2_400_000_000 and len(t) == len(w) == len(a)
    assert m.imu_for(before) is not None and m.report.ff_windows_imu_lost == 1


def test_feedforward_windows_across_a_clock_that_went_back_are_not_solved():
    """A clock that jumps back 0.6 s and runs up to the newest stamp again: 0.6 s of real time passed between
    two samples 5 ms apart in stamps, an outage no window may span."""
    f = RecordingFilter()
    f.config = SimpleNamespace(max_imu_outage_s=0.5)
    m = StartupManager(lambda _native: f, StartupConfig())
    by_t = {}
    for kind, t in _stream(3.0):
        if kind == "imu":
            m.on_imu(ImuSample(t, np.zeros(3), np.array([0, 0, 9.81])))
            if t == 1_300_000_000:
                for back in range(700_000_000, 1_300_000_001, 5_000_000):
                    m.on_imu(ImuSample(back, np.zeros(3), np.array([0, 0, 9.81])))
        else:
            by_t[t] = Frame(t, np.zeros((4, 4), np.uint8))
            m.on_tracks(t, np.zeros(0, np.int64), np.zeros((0, 2)), by_t[t])
    spanning = [by_t[t] for t in (1_000_000_000, 1_200_000_000, 1_400_000_000, 1_600_000_000, 1_800_000_000)]
    after = [by_t[t] for t in (1_400_000_000, 1_600_000_000, 1_800_000_000, 2_000_000_000, 2_200_000_000)]
    assert m.imu_for(spanning) is None and m.report.ff_windows_imu_lost == 1
    assert m.imu_for(after) is not None
    # a window before the jump, whose stamps the clock ran through again: its own samples only, in order
    before = [by_t[t] for t in (400_000_000, 600_000_000, 800_000_000, 1_000_000_000, 1_200_000_000)]
    t, _, _ = m.imu_for(before)
    assert np.all(np.diff(t) > 0) and len(t) == len(np.unique(t))


def test_feedforward_windows_across_an_imu_outage_are_not_solved():
    """A gap over msckf.max_imu_outage_s before any filter publishes: a window spanning it had its IMU
    interpolated across the outage."""
    def native(_native):
        f = RecordingFilter()
        f.config = SimpleNamespace(max_imu_outage_s=0.5)
        return f

    m = StartupManager(native, StartupConfig())
    by_t = _feed(m, keep_imu=lambda t: not 1_300_000_000 < t < 1_900_000_000)     # 0.6 s without IMU
    spanning = [by_t[t] for t in (1_000_000_000, 1_200_000_000, 1_400_000_000, 1_600_000_000, 1_800_000_000)]
    after = [by_t[t] for t in (2_000_000_000, 2_200_000_000, 2_400_000_000, 2_600_000_000, 2_800_000_000)]
    assert m.imu_for(spanning) is None and m.report.ff_windows_imu_lost == 1
    assert m.imu_for(after) is not None
