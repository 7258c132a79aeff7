"""HealthWindows: the camera-time windows the MSCKF's divergence is judged on, frame by frame against
counts worked out by hand."""
from __future__ import annotations

import numpy as np

from runtime.msckf.config import MsckfConfig
from runtime.msckf.filter_state import FilterCounters
from runtime.msckf.health import HealthWindows
from runtime.msckf.state import State

S = 1_000_000_000      # ns
DT = 100_000_000       # 10 Hz frames


def _state() -> State:
    st = State(np.eye(3), np.zeros(3), 0.0, False, False, None)
    st.P[:15, :15] = np.eye(15) * 1e-4
    return st


def test_the_blind_count_is_judged_a_window_after_it_starts_and_a_low_parallax_frame_restarts_it() -> None:
    cfg = MsckfConfig(visual_health_window_s=1.0, visual_health_after_zupt_s=1.0, min_visual_measurements=10,
                      max_time_without_update_s=100.0)
    health, counters, st = HealthWindows(cfg), FilterCounters(), _state()
    health.clear()
    # 3 accepted a frame from t = 0: after 1 s (11 frames in the window's span with 1 ms slack: 0.0 .. 1.0 s,
    # the one at 0.0 slid out) the window holds 10 frames = 30 measurements, judged healthy
    for k in range(11):
        health.add_update(k * DT, 3, 0, low_parallax=False)
        assert health.judge(st, k * DT, True, counters) is None
    assert counters.visual_accepted_min == 30
    # a frame without parallax restarts the count: nothing is judged for the next second, however blind
    t = 11 * DT
    health.add_update(t, 0, 0, low_parallax=True)
    for k in range(12, 21):
        health.add_update(k * DT, 0, 0, low_parallax=False)
        assert health.judge(st, k * DT, True, counters) is None, k
    # one window after the restart (t = 2.1 s) the window holds ten blind frames (1.2 .. 2.1 s): reset
    health.add_update(21 * DT, 0, 0, low_parallax=False)
    reason = health.judge(st, 21 * DT, True, counters)
    assert reason is not None and reason.startswith("only 0 visual measurements accepted over 1 s")
    assert counters.visual_accepted_min == 0


def test_the_chi2_share_is_judged_over_its_window_once_enough_were_tested() -> None:
    cfg = MsckfConfig(chi2_health_window_s=1.0, min_chi2_health_tests=100, max_chi2_rejection_fraction=0.5,
                      min_visual_measurements=0, max_time_without_update_s=100.0)
    health, counters, st = HealthWindows(cfg), FilterCounters(), _state()
    health.clear()
    # 8 accepted + 12 rejected a frame: 20 tested, 60 % rejected; judged from the fifth frame (100 tested)
    reasons = []
    for k in range(6):
        health.add_update(k * DT, 8, 12, low_parallax=False)
        reasons.append(health.judge(st, k * DT, True, counters))
    assert reasons[:4] == [None] * 4
    assert reasons[4] == "chi-square rejected 60 of 100 visual measurements over 1 s (> 50%)"
    assert counters.chi2_rejection_fraction_max == 0.6
    # frames older than the window slide out: after 1 s of clean frames the share is judged on them alone
    for k in range(6, 17):
        health.add_update(k * DT, 20, 0, low_parallax=False)
        last = health.judge(st, k * DT, True, counters)
    assert last is None and sum(n for _, n, _ in health.chi2) == 200


def test_starvation_counts_camera_time_since_the_last_frame_that_updated() -> None:
    cfg = MsckfConfig(max_time_without_update_s=0.5, min_visual_measurements=0)
    health, counters, st = HealthWindows(cfg), FilterCounters(), _state()
    health.clear()
    assert health.judge(st, 0, False, counters) is None        # the first frame starts the clock
    assert health.judge(st, 5 * DT, False, counters) is None    # 0.5 s: not more than the limit
    assert health.judge(st, 6 * DT, False, counters) == "no feature update for 0.60 s"
    assert health.judge(st, 7 * DT, True, counters) is None
    health.clear()
    assert health.judge(st, 20 * S, False, counters) is None    # cleared: the clock starts again


def test_a_low_parallax_frames_rejections_count_and_a_restart_waits_its_own_time() -> None:
    """A frame without parallax restarts the blind count but its chi-square tests still count; a restart
    after a zero-velocity update is judged `needed_s` later, not one window later; `clear` empties the
    chi-square window too."""
    cfg = MsckfConfig(visual_health_window_s=1.0, visual_health_after_zupt_s=2.0, min_visual_measurements=10,
                      chi2_health_window_s=1.0, min_chi2_health_tests=10, max_chi2_rejection_fraction=0.5,
                      max_time_without_update_s=100.0)
    health, counters, st = HealthWindows(cfg), FilterCounters(), _state()
    health.clear()
    health.add_update(0, 0, 12, low_parallax=True)     # 12 tested, all rejected, on a low-parallax frame
    assert health.judge(st, 0, True, counters) == ("chi-square rejected 12 of 12 visual measurements over "
                                                   "1 s (> 50%)")
    health.clear()
    assert len(health.chi2) == 0 and health.judge(st, 0, True, counters) is None
    # a zero-velocity update at t = 1 s: blind frames from then on are judged only 2 s later
    health.restart(cfg.visual_health_after_zupt_s, 10 * DT)
    for k in range(11, 30):
        health.add_update(k * DT, 0, 0, low_parallax=False)
        assert health.judge(st, k * DT, True, counters) is None, k
    health.add_update(30 * DT, 0, 0, low_parallax=False)
    assert health.judge(st, 30 * DT, True, counters).startswith("only 0 visual measurements")


def test_the_blind_count_starts_while_the_window_fills_only_if_it_is_not_running() -> None:
    """While nothing is counted yet, each frame before the clone window can triangulate moves the blind
    count's start to itself (the count runs from the last one); once frames are counted, they do not."""
    cfg = MsckfConfig(visual_health_window_s=1.0, visual_health_after_zupt_s=1.0, min_visual_measurements=10,
                      max_time_without_update_s=100.0)
    health, counters, st = HealthWindows(cfg), FilterCounters(), _state()
    health.clear()
    health.waiting_for_clones(0)
    for k in range(1, 10):
        health.waiting_for_clones(k * DT)      # the window is empty: the start follows the filling frames
    assert health.accepted_since == 9 * DT
    health.add_update(10 * DT, 0, 0, low_parallax=False)
    health.waiting_for_clones(11 * DT)         # counting: its start stays
    assert health.accepted_since == 9 * DT
    assert health.judge(st, 18 * DT, True, counters) is None
    assert health.judge(st, 19 * DT, True, counters).startswith("only 0 visual measurements")
