"""The odometry-to-map correction over sensor time: live blending and the final re-export (runtime/graph)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from runtime.geometry import make_pose, so3_exp, so3_log
from runtime.graph.correction import (
    CorrectionConfig,
    CorrectionTimeline,
    PublishedCorrection,
    final_corrections,
)
from runtime.graph.factors import GraphError

S = 1_000_000_000
STEP = S // 200                                            # 200 Hz publishing


def yaw_pose(yaw_deg: float, p) -> np.ndarray:
    return make_pose(so3_exp(np.array([0.0, 0.0, math.radians(yaw_deg)])), np.asarray(p, dtype=float))


def rand_pose(rng: np.random.Generator) -> np.ndarray:
    return make_pose(so3_exp(rng.normal(size=3)), rng.normal(size=3))


def pose_step(A: np.ndarray, B: np.ndarray) -> tuple[float, float]:
    """(|dp| m, rotation angle rad) between two poses."""
    return (float(np.linalg.norm(B[:3, 3] - A[:3, 3])),
            float(np.linalg.norm(so3_log(A[:3, :3].T @ B[:3, :3]))))


def test_config_holds_the_paper_numbers():
    c = CorrectionConfig()
    assert (c.trans_threshold_m, c.rot_threshold_deg, c.interpolation_s) == (0.05, 2.0, 1.0)
    assert c.interpolation_ns == S
    with pytest.raises(GraphError):
        CorrectionConfig(interpolation_s=-1.0)


def test_no_commit_is_identity_and_leaves_poses_unchanged():
    rng = np.random.default_rng(0)
    tl = CorrectionTimeline()
    T, v, f = tl.at(123)
    np.testing.assert_array_equal(T, np.eye(4))
    assert (v, f) == (0, 1.0)
    t = np.arange(0, 3 * S, STEP // 7, dtype=np.int64)
    T_OI = np.stack([rand_pose(rng) for _ in t])
    causal = np.stack([tl.apply(int(ti), Ti).T_MI for ti, Ti in zip(t, T_OI, strict=True)])
    final = final_corrections(t, np.zeros(0, dtype=np.int64), np.zeros((0, 4, 4))) @ T_OI
    np.testing.assert_array_equal(causal, T_OI)           # causal.tum == odometry.tum
    np.testing.assert_array_equal(final, causal)          # final.tum == causal.tum


def test_blend_is_continuous_ends_at_target_and_records_version_and_fraction():
    tl = CorrectionTimeline()
    A = yaw_pose(10.0, [1.0, 2.0, 0.5])
    assert tl.commit(2 * S, A, 1) is True                  # from identity: large change, blended
    end_A = 3 * S
    B = yaw_pose(-20.0, [0.0, -1.0, 0.2])
    t_b = 2 * S + S // 2 + 1234                            # arrives mid-blend of A
    T_mid_before, _, _ = tl.at(t_b)
    assert tl.commit(t_b, B, 2) is True
    t = np.arange(0, 5 * S, STEP, dtype=np.int64)
    t = np.union1d(t, [2 * S, t_b, end_A, t_b + S])
    out = [tl.at(int(ti)) for ti in t]
    Ts = np.stack([o[0] for o in out])
    vers = np.array([o[1] for o in out])
    fr = np.array([o[2] for o in out])

    # the largest per-step change a 1 s blend can cause at 200 Hz (the extra stamps only shorten steps)
    dp_max = 0.0
    dr_max = 0.0
    for a, b in zip(Ts[:-1], Ts[1:], strict=True):
        dp, dr = pose_step(a, b)
        dp_max, dr_max = max(dp_max, dp), max(dr_max, dr)
    dp_A, dr_A = pose_step(np.eye(4), A)
    dp_B, dr_B = pose_step(T_mid_before, B)
    bound_p = max(dp_A, dp_B) * STEP / S * (1 + 1e-9)
    bound_r = max(dr_A, dr_B) * STEP / S * (1 + 1e-9)
    assert dp_max <= bound_p and dr_max <= bound_r
    # the commit mid-blend starts exactly where the blend was
    np.testing.assert_allclose(tl.at(t_b)[0], T_mid_before, atol=1e-15)

    # versions and fractions
    assert np.all(vers[t < 2 * S] == 0) and np.all(fr[t < 2 * S] == 1.0)
    in_a = (t >= 2 * S) & (t < t_b)
    assert np.all(vers[in_a] == 1)
    np.testing.assert_allclose(fr[in_a], (t[in_a] - 2 * S) / S)
    in_b = (t >= t_b) & (t < t_b + S)
    assert np.all(vers[in_b] == 2)
    np.testing.assert_allclose(fr[in_b], (t[in_b] - t_b) / S)
    assert np.all((fr >= 0.0) & (fr <= 1.0))
    # B is reached exactly one sensor second after its commit and held
    after = t >= t_b + S
    assert np.all(vers[after] == 2) and np.all(fr[after] == 1.0)
    for T in Ts[after]:
        np.testing.assert_array_equal(T, B)
    assert tl.version == 2 and len(tl) == 2


def test_blend_ends_exactly_at_target_after_one_second():
    tl = CorrectionTimeline()
    T = yaw_pose(5.0, [0.3, 0.0, 0.0])
    tl.commit(S, T, 7)
    T_end, v, f = tl.at(2 * S)
    np.testing.assert_array_equal(T_end, T)
    assert (v, f) == (7, 1.0)
    T_before, _, f = tl.at(2 * S - 1)
    assert f < 1.0 and pose_step(T_before, T)[0] < 1e-9


def test_small_change_applies_at_once():
    tl = CorrectionTimeline()
    A = yaw_pose(30.0, [5.0, 0.0, 0.0])
    tl.commit(S, A, 1)
    small = A @ make_pose(so3_exp(np.array([0.0, math.radians(1.9), 0.0])), np.array([0.0, 0.03, 0.0]))
    assert tl.commit(3 * S, small, 2) is False
    T, v, f = tl.at(3 * S)
    np.testing.assert_array_equal(T, small)
    assert (v, f) == (2, 1.0)
    # a change just above either threshold is blended
    big_p = small @ make_pose(np.eye(3), np.array([0.0, 0.0, 0.051]))
    assert tl.commit(5 * S, big_p, 3) is True
    assert tl.at(5 * S + S // 4)[1:] == (3, 0.25)
    assert tl.commit(7 * S, big_p, 4) is False                  # blend over: no change, immediate
    assert tl.commit(8 * S, big_p @ yaw_pose(2.1, [0.0, 0.0, 0.0]), 5) is True


def test_geodesic_rotation_midpoint():
    tl = CorrectionTimeline()
    target = yaw_pose(90.0, [2.0, -4.0, 1.0])
    tl.commit(0, target, 1)
    T, v, f = tl.at(S // 2)
    assert (v, f) == (1, 0.5)
    np.testing.assert_allclose(so3_log(T[:3, :3]), [0.0, 0.0, math.radians(45.0)], atol=1e-12)
    np.testing.assert_allclose(T[:3, 3], [1.0, -2.0, 0.5], atol=1e-12)


def test_apply_composes_correction_and_odometry_pose():
    rng = np.random.default_rng(1)
    tl = CorrectionTimeline()
    C = rand_pose(rng)
    tl.commit(0, C, 1)
    T_OI = rand_pose(rng)
    pub = tl.apply(3 * S, T_OI)
    assert isinstance(pub, PublishedCorrection)
    np.testing.assert_allclose(pub.T_MI, C @ T_OI, atol=1e-12)
    assert (pub.version, pub.fraction) == (1, 1.0)


def test_bad_commits_raise_clear_errors():
    tl = CorrectionTimeline()
    tl.commit(2 * S, np.eye(4), 3)
    with pytest.raises(ValueError, match="version"):
        tl.commit(3 * S, np.eye(4), 3)
    with pytest.raises(ValueError, match="older"):
        tl.commit(S, np.eye(4), 4)
    with pytest.raises(ValueError, match="rigid"):
        tl.commit(3 * S, 2.0 * np.eye(4), 4)
    with pytest.raises(ValueError, match="version"):
        CorrectionTimeline().commit(0, np.eye(4), 0)
    assert len(tl) == 1


def test_final_corrections_single_node_is_constant():
    rng = np.random.default_rng(2)
    C = rand_pose(rng)
    t = np.array([-5 * S, 0, S, 10 * S], dtype=np.int64)
    out = final_corrections(t, np.array([S]), C[None])
    for T in out:
        np.testing.assert_array_equal(T, C)


def test_final_corrections_two_nodes_midpoint_and_clamping():
    A = yaw_pose(0.0, [0.0, 0.0, 0.0])
    B = yaw_pose(90.0, [2.0, 4.0, -2.0])
    t = np.array([0, S, 2 * S, 3 * S, 9 * S], dtype=np.int64)
    out = final_corrections(t, np.array([3 * S, S]), np.stack([B, A]))        # any node order
    np.testing.assert_array_equal(out[0], A)
    np.testing.assert_array_equal(out[1], A)
    np.testing.assert_allclose(out[2][:3, 3], [1.0, 2.0, -1.0], atol=1e-12)
    np.testing.assert_allclose(so3_log(out[2][:3, :3]), [0.0, 0.0, math.radians(45.0)], atol=1e-12)
    np.testing.assert_array_equal(out[3], B)
    np.testing.assert_array_equal(out[4], B)


def test_final_corrections_bad_input():
    with pytest.raises(GraphError, match="share"):
        final_corrections(np.array([0]), np.array([1, 1]), np.stack([np.eye(4)] * 2))
    with pytest.raises(GraphError, match="shape"):
        final_corrections(np.array([0]), np.array([1, 2]), np.eye(4)[None])
