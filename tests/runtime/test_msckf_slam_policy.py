"""Which tracks become SLAM landmarks and when landmarks leave the state (OpenVINS's policy)."""

from __future__ import annotations

import numpy as np

from runtime.msckf.config import MsckfConfig
from runtime.msckf.estimator import MsckfEstimator
from tests.runtime.test_msckf_estimator import _init, _rig, _stream

CFG = MsckfConfig(max_time_without_update_s=1000.0, dt_slam_delay=0.0)


def _feed(est: MsckfEstimator, imu: list, k: int, frame: tuple) -> int:
    """Feed the IMU up to one frame past it and the frame's tracks; returns the next IMU index."""
    t_ns, ids, uv = frame
    while k < len(imu) and imu[k].t_ns <= t_ns + 5_000_000:
        est.feed_imu(imu[k])
        k += 1
    est.feed_tracks(t_ns, ids, uv)
    return k


def test_new_landmarks_are_the_earliest_created_full_window_tracks() -> None:
    """When more full-window tracks compete than there are free landmark slots, the new landmarks come
    from the ones that entered the database first (its creation order, read before each frame)."""
    imu, frames = _stream(6.0)
    est = MsckfEstimator(_rig(), CFG.updated(max_slam=6, feature_order_seed=3))
    _init(est, np.zeros(3))
    k, checked = 0, 0
    for frame in frames:
        st = est.state_
        before = set(st.slam)
        seen = set(frame[1].tolist())
        full = []
        if len(st.clones) >= min(CFG.max_clones, 5):      # this frame's clone makes the window full
            marg_t = st.clone_times()[0]
            # in creation order; this frame adds one observation to each seen track
            full = [fid for fid, tr in est.db.tracks.items() if fid not in st.slam and fid in seen
                    and tr.t_ns[0] <= marg_t and len(tr) + 1 > CFG.max_clones]
        k = _feed(est, imu, k, frame)
        new = set(est.state_.slam) - before
        free = est.config.max_slam - len(before)
        if new and 0 < free < len(full):
            assert new <= set(full[:free]), (sorted(new), full[:free], full)
            checked += 1
    assert checked >= 3


def _corrupt_one_landmark(cfg: MsckfConfig, hits_wanted: int = 3) -> tuple[MsckfEstimator, int, list[bool]]:
    """Shift one tracked landmark's observation by 40 px in hits_wanted frames; returns the estimator, the
    landmark id and, after each corrupted frame, whether the landmark was still in the state."""
    imu, frames = _stream(5.0)
    est = MsckfEstimator(_rig(), cfg)
    _init(est, np.zeros(3))
    k, target, still = 0, None, []
    for frame in frames:
        t_ns, ids, uv = frame
        st = est.state_
        if target is None and st is not None and st.slam:
            cand = [fid for fid in st.slam if fid in set(ids.tolist())]
            if cand:
                target = cand[0]
        if target is not None and len(still) < hits_wanted and target in set(ids.tolist()):
            if still and not still[-1]:
                break
            uv = uv.copy()
            uv[ids == target] += 40.0
            rejected_before = est.report()["slam_chi2_rejected"]
            k = _feed(est, imu, k, (t_ns, ids, uv))
            assert est.report()["slam_chi2_rejected"] > rejected_before
            still.append(target in est.state_.slam)
            continue
        k = _feed(est, imu, k, frame)
        if target is not None and len(still) == hits_wanted:
            break
    return est, target, still


def test_a_landmark_leaves_after_its_second_chi_square_rejection() -> None:
    """OpenVINS 2.7 (UpdaterSLAM.cpp, VioManager.cpp): each chi-square rejection of a landmark's observation
    increments its update_fail_count, and a landmark whose count exceeds 1 is marginalised."""
    est, target, still = _corrupt_one_landmark(CFG.updated(max_slam=10, slam_max_chi2_failures=1))
    assert still == [True, False]
    assert est.report()["slam_marginalized"] >= 1


def test_by_default_a_rejection_drops_only_the_observation() -> None:
    """slam_max_chi2_failures None (the default, better than OpenVINS's rule at 20 Hz): three rejected
    observations, and the landmark stays in the state while it is tracked, and keeps being updated."""
    assert CFG.slam_max_chi2_failures is None
    est, target, still = _corrupt_one_landmark(CFG.updated(max_slam=10))
    assert still == [True, True, True]
    assert target in est.state_.slam and est.state_.slam[target].fail_count == 0
