"""The start-up's adoption of a camera-IMU time offset its feed-forward windows found
(runtime/startup.py, runtime/ffinit/time_offset_check.py): when findings agree, what takes the offset up."""
from __future__ import annotations

import numpy as np
import pytest
from startup_fakes import RecordingFilter

from runtime.ffinit.window import Rejection
from runtime.msckf.init_common import InitResult
from runtime.startup import StartupConfig, StartupManager


class OffsetFilter(RecordingFilter):
    """A fake filter that keeps the time offset it is told."""

    def set_time_offset(self, time_offset_s):
        self.offset_told = time_offset_s


def _manager(cfg: StartupConfig | None = None, adopt: bool = True):
    filters, adopted = [], []

    def make(native):
        f = OffsetFilter()
        filters.append(f)
        return f

    m = StartupManager(make, cfg, time_offset_s=0.0, imu_lead_s=0.22,
                       adopt_time_offset=adopted.append if adopt else None)
    return m, filters, adopted


def _finding(offset_s: float) -> Rejection:
    return Rejection("time_offset", "fits another offset", time_offset_s=offset_s)


def _fed(m: StartupManager, seconds: float, frames: bool = True, lost_at_ns: tuple = (),
         after_s: float = -1.0):
    """Feed the fake stream's events after `after_s` up to `seconds` to `m`, yielding each event's stamp once
    it is in (IMU samples at `lost_at_ns` carry the driver's loss flag)."""
    from startup_fakes import stream

    from runtime.events import Frame, ImuSample

    for kind, t in stream(seconds):
        if t <= after_s * 1e9:
            continue
        if kind == "imu":
            m.on_imu(ImuSample(t, np.zeros(3), np.array([0, 0, 9.81]), lost_before=int(t in lost_at_ns)))
        else:
            frame = Frame(t, np.zeros((4, 4), np.uint8)) if frames else None
            m.on_tracks(t, np.arange(3), np.zeros((3, 2)), frame)
        yield t


def _feed(m: StartupManager, seconds: float, **kwargs) -> None:
    for _ in _fed(m, seconds, **kwargs):
        pass


def test_two_agreeing_findings_are_adopted_by_the_start_up_its_native_filter_and_the_caller():
    m, filters, adopted = _manager(StartupConfig(time_offset_findings=2))
    m.on_feedforward(_finding(0.061))
    assert adopted == [] and m.report.time_offset_adopted_s is None and m.offset_ns == 0
    m.on_feedforward(_finding(0.055))
    assert adopted == [pytest.approx(0.058)] and m.report.time_offset_adopted_s == pytest.approx(0.058)
    assert m.offset_ns == 58_000_000                     # later windows' IMU is taken at the adopted offset
    assert filters[0].offset_told == pytest.approx(0.058)
    assert m.report.time_offset_findings == 2 and m.report.ff_rejections == {"time_offset": 2}


def test_findings_that_disagree_are_not_adopted_and_only_the_recent_ones_count():
    m, _, adopted = _manager(StartupConfig(time_offset_findings=2))
    m.on_feedforward(_finding(0.06))
    m.on_feedforward(_finding(-0.04))                    # 100 ms apart: not adopted
    assert adopted == []
    m.on_feedforward(_finding(-0.035))                   # agrees with the one before
    assert adopted == [pytest.approx(-0.0375)] and m.report.time_offset_findings == 3


def test_an_accepted_window_solved_at_another_offset_counts_and_its_candidate_starts_there():
    m, filters, adopted = _manager(StartupConfig(time_offset_findings=1))
    _feed(m, 1.5, frames=False)
    res = InitResult(1_000_000_000, np.eye(3), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), None,
                     "feedforward")
    res.info.update(time_offset_s=-0.03, time_offset_shift_s=-0.03, time_offset_detail="fits -30 ms")
    m.on_feedforward(res)
    assert m.report.candidates_started == 1 and filters[-1].time_offset_s == -0.03
    assert m.report.ff_time_offset_corrected == 1 and m.report.ff_time_offset_s == -0.03
    assert m.report.ff_time_offset_first == "fits -30 ms" and adopted == [pytest.approx(-0.03)]


def test_by_default_the_first_finding_is_adopted_and_a_later_one_relative_to_it_adopts_again():
    m, filters, adopted = _manager()
    m.on_feedforward(_finding(0.04))
    assert adopted == [pytest.approx(0.04)] and m.offset_ns == 40_000_000
    m.on_feedforward(_finding(-0.01))           # found against the adopted offset: the windows' new finding
    assert adopted == [pytest.approx(0.04), pytest.approx(-0.01)] and filters[0].offset_told == -0.01


def test_the_first_findings_detail_is_kept_whatever_the_window_ended_as():
    """A finding may come with a refusal a longer span can cure (its reason kept): its detail is still the
    report's first finding."""
    m, _, adopted = _manager()
    m.on_feedforward(Rejection("scale_unobservable", "at the offset the rotations fit (+40 ms ...): short",
                               time_offset_s=0.04))
    m.on_feedforward(_finding(0.041))
    assert m.report.time_offset_first.startswith("at the offset the rotations fit (+40 ms")
    assert m.report.ff_rejections == {"scale_unobservable": 1, "time_offset": 1} and len(adopted) == 2


def test_without_a_caller_findings_are_only_counted():
    m, filters, adopted = _manager(adopt=False)
    for _ in range(3):
        m.on_feedforward(_finding(0.06))
    assert m.report.time_offset_findings == 3 and m.report.time_offset_adopted_s is None
    assert m.offset_ns == 0 and not hasattr(filters[0], "offset_told")


def test_the_window_imu_reaches_back_by_the_lead():
    """The arrays handed to a window's solve start imu_lead_s before its first image (the time-offset scan
    looks there), not only the 20 ms margin."""
    m, _, _ = _manager()
    _feed(m, 2.0)
    frames = m.window()
    t, _, _ = m.imu_for(frames)
    assert t[0] <= frames[0].t_ns - 220_000_000 < t[0] + 5_000_000


@pytest.mark.parametrize("field", ["time_offset_findings", "time_offset_agree_s"])
def test_config_refuses_non_positive_values(field):
    from runtime.errors import ConfigError

    with pytest.raises(ConfigError, match=field):
        StartupConfig(**{field: 0})


def test_with_a_positive_offset_windows_end_at_the_newest_frame_the_imu_covers():
    """t_imu = t_cam + 120 ms: the newest frames wait for the IMU (more than two frame periods behind), so
    a window ending at the newest frame would never be covered; it ends at the newest covered one."""
    m = StartupManager(lambda native: OffsetFilter(), StartupConfig(), time_offset_s=0.12)
    solvable = []
    for t in _fed(m, 2.0):
        frames = m.window()
        if frames is not None:
            assert frames[-1].t_ns + 120_000_000 <= t         # covered by the IMU received so far
            if m.imu_for(frames) is not None:
                solvable.append(frames[-1].t_ns)
                m.note_request(frames)
    assert len(solvable) >= 4 and np.all(np.diff(solvable) >= 200_000_000 * 0.999)


def test_a_finding_after_another_filter_published_is_only_counted():
    """The publishing filter's state was propagated at its offset: an answer that arrives after it started
    (its window was requested before) must not move it."""
    m, filters, adopted = _manager()
    m.publisher = filters[0]
    m.on_feedforward(_finding(0.05))
    assert m.report.time_offset_findings == 1 and adopted == [] and m.report.time_offset_adopted_s is None
    assert not hasattr(filters[0], "offset_told") and m.offset_ns == 0


def test_a_candidate_replaying_at_another_offset_is_dropped_on_adoption_and_not_counted_as_tried():
    m, filters, adopted = _manager(StartupConfig(max_candidates=1))
    _feed(m, 1.5)
    m.on_feedforward(InitResult(1_000_000_000, np.eye(3), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3),
                                None, "feedforward"))
    assert m.report.candidates_started == 1 and len(m.candidates) == 1
    filters[-1].time_offset_s = 0.0                       # started at the offset then in use
    m.on_feedforward(_finding(0.06))
    assert adopted == [pytest.approx(0.06)] and m.candidates == [] and m.report.candidates_offset_dropped == 1
    res = InitResult(1_200_000_000, np.eye(3), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), None,
                     "feedforward")
    m.on_feedforward(res)                                 # max_candidates = 1: the dropped one did not count
    assert m.report.candidates_started == 2


def test_a_corrected_candidate_replays_from_the_frames_after_its_state_at_its_own_offset():
    m, filters, _ = _manager(adopt=False)            # the start-up's offset stays 0
    _feed(m, 1.5)
    res = InitResult(1_000_000_000, np.eye(3), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), None,
                     "feedforward")
    res.info.update(time_offset_s=0.2, time_offset_shift_s=0.2, time_offset_detail="fits +200 ms")
    m.on_feedforward(res)
    cand = m.candidates[0]
    cand.step(m.buffer, None)
    first_tracks = next(t for kind, t in filters[-1].fed if kind == "tracks")
    # the first frame whose t_cam + 0.2 s follows the state's 1.0 s, though it precedes the IMU replayed from
    # 50 ms before the state (at the start-up's own offset, 0, the replay began after it)
    assert first_tracks == 850_000_000


def test_re_solves_also_end_at_the_newest_frame_the_imu_covers():
    """t_imu = t_cam + 120 ms: a refused window's re-solves use covered frames, so they run."""
    from types import SimpleNamespace

    m = StartupManager(lambda native: OffsetFilter(), StartupConfig(), time_offset_s=0.12)
    _feed(m, 1.2)
    frames = m.window()
    seed = SimpleNamespace(t_cam_ns=np.array([f.t_ns for f in frames], np.int64),
                           last_ns=int(frames[-1].t_ns))
    m.note_request(frames)
    m.on_feedforward(Rejection("scale_unobservable", "short", seed=seed))
    assert m.extension_pending()
    for t in _fed(m, 2.0, after_s=1.2):
        due = m.extension()
        if due is not None and m.extension_imu(due[1]) is not None:
            covered_at = t
            break
    else:
        pytest.fail("no re-solve was ever covered by the IMU")
    assert due[1][-1] + 120_000_000 <= covered_at


def test_an_imu_loss_before_a_window_shortens_the_lead_and_one_inside_refuses_it():
    m, _, _ = _manager()
    _feed(m, 2.0, lost_at_ns=(1_100_000_000,))
    frames = m.window()                                   # 1.2 ... 2.0 s: the loss is 100 ms before it
    t, _, _ = m.imu_for(frames)
    assert t[0] == 1_100_000_000 and m.report.ff_windows_imu_lost == 0
    m2, _, _ = _manager()
    _feed(m2, 2.0, lost_at_ns=(1_500_000_000,))            # inside the window
    assert m2.imu_for(m2.window()) is None and m2.report.ff_windows_imu_lost == 1


def test_a_gap_across_a_windows_end_flagged_after_it_is_counted_as_lost():
    """Samples lost from before a window's last image to after it, the flag on the first sample past the
    gap: the window can never be covered, and is counted once as lost instead of waiting silently."""
    from startup_fakes import stream

    from runtime.events import Frame, ImuSample

    m, _, _ = _manager()
    gap = (1_960_000_000, 2_060_000_000)                  # samples missing around the 2.0 s frame
    for kind, t in stream(2.2):
        if kind == "imu":
            if gap[0] <= t < gap[1]:
                continue
            m.on_imu(ImuSample(t, np.zeros(3), np.array([0, 0, 9.81]), lost_before=int(t == gap[1])))
        else:
            m.on_tracks(t, np.arange(3), np.zeros((3, 2)), Frame(t, np.zeros((4, 4), np.uint8)))
    frames = [f for f in m._frames if f.t_ns <= 2_000_000_000][-17::4]    # 1.2 ... 2.0 s
    assert [f.t_ns for f in frames][-1] == 2_000_000_000
    assert m.imu_for(frames) is None and m.report.ff_windows_imu_lost == 1
    assert m.imu_for(frames) is None and m.report.ff_windows_imu_lost == 1     # counted once
