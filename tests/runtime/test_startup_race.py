"""The race between the native initializer and feed-forward candidates (runtime/startup.py): who
publishes when both become ready, the catch-up and abandonment boundaries, candidate divergence and the
restart after the publishing filter diverges."""
from __future__ import annotations

import numpy as np
import pytest
from startup_fakes import RecordingFilter
from startup_fakes import stream as _stream

from runtime.events import Frame, ImuSample
from runtime.msckf.init_common import InitResult
from runtime.startup import StartupConfig, StartupManager

MS = 1_000_000
"""Nanoseconds per millisecond."""


class ResettingFilter(RecordingFilter):
    """A RecordingFilter that diverges (resets to uninitialised, as MsckfEstimator.reset does) at the
    first frame at or after `reset_at_ns`, once."""

    def __init__(self, native_init_at_ns: int | None = None, reset_at_ns: int | None = None) -> None:
        super().__init__(native_init_at_ns)
        self.reset_at_ns = reset_at_ns

    def feed_tracks(self, t, ids, uv):
        if self.reset_at_ns is not None and self.t_init is not None and t >= self.reset_at_ns:
            self.reset_at_ns = None
            self.t_init, self.init_source, self.pending = None, None, []
        return super().feed_tracks(t, ids, uv)


def _factory(*filters: RecordingFilter):
    """make_filter handing out `filters` in order: the native filter first, then one per candidate."""
    queue = list(filters)
    return lambda native: queue.pop(0)


def _ff_state(t_ns: int) -> InitResult:
    """A feed-forward state at t_ns (IMU clock)."""
    return InitResult(t_ns, np.eye(3), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), None,
                      "feedforward")


def _feed(m: StartupManager, events, offers=(), until_ns: int | None = None) -> list:
    """Feed `events` (up to and including until_ns); offers: (deliver_at_ns, state_ns) feed-forward
    results handed to the manager after the first event at or after deliver_at_ns. Returns what was
    published."""
    pending = sorted(offers)
    out = []
    for kind, t in events:
        if until_ns is not None and t > until_ns:
            break
        if kind == "imu":
            out += m.on_imu(ImuSample(t, np.zeros(3), np.array([0, 0, 9.81])))
        else:
            out += m.on_tracks(t, np.arange(3), np.zeros((3, 2)), Frame(t, np.zeros((4, 4), np.uint8)))
        while pending and t >= pending[0][0]:
            m.on_feedforward(_ff_state(pending.pop(0)[1]))
    return out



def _never_replaying() -> StartupConfig:
    """A configuration whose candidates never replay (to watch the window and candidate bookkeeping alone):
    replay_batch = 0 is refused as a setting, so it is set after the checks."""
    cfg = StartupConfig()
    cfg.replay_batch = 0
    return cfg

def test_native_ready_while_a_candidate_replays_publishes_and_drops_the_candidate():
    """A candidate replaying slowly (one buffered measurement per live one) is still behind when the
    native filter initialises at 2.5 s: the native filter publishes, the candidate is dropped unselected
    and fed nothing more."""
    native, cand = RecordingFilter(native_init_at_ns=2500 * MS), RecordingFilter()
    m = StartupManager(_factory(native, cand), StartupConfig(replay_batch=1))
    pub = _feed(m, _stream(4.0), offers=[(2000 * MS, 200 * MS)])
    assert m.report.candidates_started == 1 and m.report.candidates_selected == 0
    assert m.report.candidates_abandoned == 0 and m.report.candidates_diverged == 0
    assert m.report.candidates_outrun == 1  # every started candidate ends in exactly one counter
    assert m.report.published_by == "native:static" and m.candidates == []
    assert pub and all(p.source == "native:static" and p.filter_id == 0 for p in pub)
    assert pub[0].t_cam_ns == 2550 * MS  # the first frame after the native initialisation
    # the candidate was still replaying old measurements when dropped, and got nothing after
    assert cand.fed[-1][1] < 2500 * MS - 150 * MS
    assert max(t for _, t in cand.fed) < m.report.first_publish_t_ns


def test_candidate_ready_before_the_native_filter_publishes_and_the_native_filter_stops():
    """The candidate is selected at 2.05 s; the native filter, armed to initialise at 2.5 s, is fed
    nothing after the selection and never publishes. Control: without the candidate it publishes."""
    native, cand = RecordingFilter(native_init_at_ns=2500 * MS), RecordingFilter()
    m = StartupManager(_factory(native, cand))
    pub = _feed(m, _stream(4.0), offers=[(2000 * MS, 1500 * MS)])
    assert m.report.published_by == "feedforward" and m.report.candidates_selected == 1
    assert m.report.candidates_outrun == 0
    assert pub[0].t_cam_ns == 2050 * MS
    assert {p.source for p in pub} == {"feedforward"} and {p.filter_id for p in pub} == {1}
    assert pub[-1].t_cam_ns == 4000 * MS  # the selected candidate follows the live stream
    # the native filter got everything up to the frame the candidate was selected on, then nothing
    assert max(t for _, t in native.fed) == 2050 * MS and not native.initialized

    control = StartupManager(_factory(RecordingFilter(native_init_at_ns=2500 * MS)))
    assert _feed(control, _stream(4.0))[0].t_cam_ns == 2550 * MS
    assert control.report.published_by == "native:static"


def test_on_the_same_measurement_the_native_filter_wins():
    """Both become ready on the same measurement (the 2.05 s frame gives the candidate its fifth live
    state and the native filter, initialised at 2.0 s, its first): the native filter is fed first and
    publishes. Control: without the native initialisation the candidate publishes that frame's state."""
    alone = StartupManager(_factory(RecordingFilter(), RecordingFilter()))
    pub_alone = _feed(alone, _stream(3.0), offers=[(2000 * MS, 1500 * MS)])
    assert alone.report.published_by == "feedforward" and pub_alone[0].t_cam_ns == 2050 * MS
    assert alone.report.first_publish_t_ns == 2050 * MS

    native = RecordingFilter(native_init_at_ns=2000 * MS)
    m = StartupManager(_factory(native, RecordingFilter()))
    pub = _feed(m, _stream(3.0), offers=[(2000 * MS, 1500 * MS)])
    assert m.report.candidates_started == 1 and m.report.candidates_selected == 0
    assert m.report.published_by == "native:static" and pub[0].t_cam_ns == 2050 * MS
    assert {p.filter_id for p in pub} == {0}


def _moved(events, t_from: int, t_to: int):
    """The event stream with the frame at t_from moved to t_to."""
    out = [("cam", t_to) if e == ("cam", t_from) else e for e in events]
    return sorted(out, key=lambda e: (e[1], e[0] != "imu"))


@pytest.mark.parametrize(("frame_ns", "catch_up_s", "first_ns"), [
    (1850 * MS, 0.15, 2050 * MS),          # 0.15 s behind the newest frame (2.00 s): live at the default
    (1850 * MS, 0.15 - 1e-9, 2100 * MS),   # just below the lag: not live, a fifth live state is needed
    (1849 * MS, 0.15, 2100 * MS),          # 0.151 s behind: not live at the default
    (1849 * MS, 0.151 + 1e-9, 2050 * MS),  # just above the lag: live
])
def test_catch_up_boundary(frame_ns, catch_up_s, first_ns):
    """A replayed state counts as live when at most catch_up_s behind the newest frame (inclusive):
    state at 1.50 s delivered at 2.00 s; the replayed 1.85 s (or 1.849 s) frame is the fifth state from
    the end when the candidate publishes at 2.05 s; without it, it publishes one frame later."""
    assert StartupConfig().catch_up_s == 0.15
    m = StartupManager(_factory(RecordingFilter(), RecordingFilter()),
                       StartupConfig(catch_up_s=catch_up_s))
    pub = _feed(m, _moved(_stream(3.0), 1850 * MS, frame_ns), offers=[(2000 * MS, 1500 * MS)])
    assert m.report.published_by == "feedforward"
    assert pub[0].t_cam_ns == first_ns


@pytest.mark.parametrize("abandon_after_s", [3.0, 1.0])
def test_abandonment_boundary(abandon_after_s):
    """A candidate created at 2.000 s (the newest IMU sample when delivered) is kept through
    2.000 + abandon_after_s and abandoned at the next IMU sample (5 ms later)."""
    assert StartupConfig().abandon_after_s == 3.0
    m = StartupManager(_factory(RecordingFilter(), RecordingFilter()),
                       StartupConfig(replay_batch=1, abandon_after_s=abandon_after_s))
    events = _stream(6.0)
    created = 2000 * MS
    kept_until = created + int(round(abandon_after_s * 1e9))
    _feed(m, [e for e in events if e[1] <= kept_until], offers=[(created, 200 * MS)])
    assert m.report.candidates_started == 1 and m.candidates[0].created_ns == created
    assert m.candidates[0].status == "replaying" and m.report.candidates_abandoned == 0
    cand = m.candidates[0]
    _feed(m, [e for e in events if kept_until < e[1] <= kept_until + 5 * MS])
    assert cand.status == "abandoned" and m.report.candidates_abandoned == 1 and m.candidates == []
    assert m.report.published_by is None


def test_windows_are_offered_until_the_fifth_candidate_has_started():
    """max_candidates = 5: window() offers a window after four started candidates, none after five."""
    assert StartupConfig().max_candidates == 5
    m = StartupManager(_factory(*[RecordingFilter() for _ in range(6)]), _never_replaying())
    _feed(m, _stream(2.0))
    for _ in range(4):
        m.on_feedforward(_ff_state(1900 * MS))
    assert m.report.candidates_started == 4 and m.window() is not None
    m.on_feedforward(_ff_state(1900 * MS))
    assert m.report.candidates_started == 5 and m.window() is None


def test_a_diverging_candidate_is_dropped_counted_and_still_uses_up_the_budget():
    """A candidate whose filter resets during its replay is dropped ("diverged", candidates_diverged)
    after the replay batch it diverged in, and fed nothing more; with max_candidates = 1 a later result
    starts no second candidate, with 2 it does and is selected."""
    native = RecordingFilter()
    bad = ResettingFilter(reset_at_ns=1700 * MS)
    m = StartupManager(_factory(native, bad, RecordingFilter()), StartupConfig(max_candidates=1))
    offers = [(2000 * MS, 1500 * MS), (2600 * MS, 2400 * MS)]
    pub = _feed(m, _stream(4.0), offers=offers)
    assert m.report.candidates_diverged == 1 and m.report.candidates_started == 1
    assert m.report.ff_accepted == 2 and m.report.published_by is None and pub == []
    after_reset = [e for e in bad.fed if e[1] > 1700 * MS]  # the frame it diverged on
    assert len(after_reset) < StartupConfig().replay_batch  # at most the rest of that batch

    native, bad, good = RecordingFilter(), ResettingFilter(reset_at_ns=1700 * MS), RecordingFilter()
    m = StartupManager(_factory(native, bad, good), StartupConfig(max_candidates=2))
    pub = _feed(m, _stream(4.0), offers=offers)
    assert m.report.candidates_diverged == 1 and m.report.candidates_started == 2
    assert m.report.published_by == "feedforward" and {p.filter_id for p in pub} == {2}


def test_restart_after_the_publisher_diverges():
    """The selected candidate diverges at 3.0 s: start-up restarts (restarts_after_divergence), that
    filter becomes the native one with its initializers armed, the candidate budget is renewed
    (max_candidates = 1 was used up) and the next publisher's states carry segment 1."""
    native = RecordingFilter()
    first = ResettingFilter(reset_at_ns=3000 * MS)
    second = RecordingFilter()
    m = StartupManager(_factory(native, first, second), StartupConfig(max_candidates=1))
    events = _stream(6.0)
    pub = _feed(m, [e for e in events if e[1] <= 3000 * MS], offers=[(2000 * MS, 1500 * MS)])
    assert m.report.published_by is None and m.report.restarts_after_divergence == 1
    assert m.report.first_published_by == "feedforward"          # who published first is kept
    assert m.native is first and m.publisher is None
    assert pub and {(p.source, p.segment) for p in pub} == {("feedforward", 0)}
    assert pub[-1].t_cam_ns < 3000 * MS

    pub = _feed(m, [e for e in events if e[1] > 3000 * MS], offers=[(4000 * MS, 3600 * MS)])
    assert m.report.candidates_started == 2 and m.report.candidates_selected == 2
    assert m.report.published_by == "feedforward"
    assert pub and {(p.source, p.segment, p.filter_id) for p in pub} == {("feedforward", 1, 2)}
    assert second.fed[0][1] >= 3600 * MS - 50 * MS  # replayed from the new state, after the restart


def test_after_a_restart_the_diverged_filter_can_publish_natively():
    """With no feed-forward result after the restart, the former candidate (now the native filter)
    re-initialises on its own at 4.0 s and publishes as native, in segment 1."""
    first = ResettingFilter(native_init_at_ns=4000 * MS, reset_at_ns=3000 * MS)
    m = StartupManager(_factory(RecordingFilter(), first))
    pub = _feed(m, _stream(6.0), offers=[(2000 * MS, 1500 * MS)])
    assert m.report.restarts_after_divergence == 1 and m.report.published_by == "native:static"
    assert m.report.first_published_by == "feedforward"
    before = [p for p in pub if p.segment == 0]
    after = [p for p in pub if p.segment == 1]
    assert before and {p.source for p in before} == {"feedforward"} and before[-1].t_cam_ns < 3000 * MS
    assert after and {p.source for p in after} == {"native:static"} and after[0].t_cam_ns == 4050 * MS
