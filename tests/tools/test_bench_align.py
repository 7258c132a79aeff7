"""`davio bench align`'s scoring against the truth on synthetic sessions whose map frames are known:
each session's "final trajectory" is its truth moved into its own map frame, so the truth-derived
transform is known in closed form and a perfect alignment scores about zero."""
from __future__ import annotations

import numpy as np
import pytest

from runtime.geometry import PoseTrajectory
from tests.runtime.test_graph_relocalize import _pose, _rz, _sessions
from tools.benchmarks.align import _parse, score


def _truth(seed: int) -> PoseTrajectory:
    rng = np.random.default_rng(seed)
    t = 10**18 + np.arange(60, dtype=np.int64) * 50_000_000
    p = np.cumsum(rng.normal(0, 0.05, (60, 3)), axis=0)
    R = np.stack([_rz(a)[:3, :3] for a in np.linspace(0, 90, 60)])
    return PoseTrajectory(t, p, R)


def _moved(traj: PoseTrajectory, T: np.ndarray) -> PoseTrajectory:
    return PoseTrajectory(traj.t_ns, traj.p @ T[:3, :3].T + T[:3, 3], T[:3, :3] @ traj.R)


def test_score_finds_no_error_when_the_alignment_is_right_and_reports_a_wrong_one():
    T_PW, T_NW = _pose(_rz(-25.0), [0.4, 1.1, 0.0]), _pose(_rz(40.0), [1.5, -2.0, 0.3])
    prior, new = _sessions(T_PW, T_NW)
    gt_a, gt_b = _truth(1), _truth(2)
    row = score(prior, new, _moved(gt_a, T_PW), _moved(gt_b, T_NW), gt_a, gt_b)
    assert row["localized"] and row["fit"] == "centres"
    assert abs(row["yaw_error_deg"]) < 0.1 and row["translation_error_m"] < 0.02   # 0.44 deg untrimmed
    assert row["b_in_a_rms_m"] < 0.03 and row["ate_a_m"] < 1e-9 and row["ate_b_m"] < 1e-9
    # B's trajectory claimed in a frame 10 deg off its views' frame: the score shows the error
    off = _pose(_rz(10.0), [0.0, 0.0, 0.0]) @ T_NW
    bad = score(prior, new, _moved(gt_a, T_PW), _moved(gt_b, off), gt_a, gt_b)
    assert abs(abs(bad["yaw_error_deg"]) - 10.0) < 0.3 and bad["b_in_a_rms_m"] > 0.1


def test_sequence_specs_are_checked():
    with pytest.raises(SystemExit, match="expected DIR:STYLE"):
        _parse("V1_02_medium:room:0:40")
    with pytest.raises(SystemExit, match="no euroc_imu_gt folder"):
        _parse("no_such_sequence:room:0:40:38:45")
