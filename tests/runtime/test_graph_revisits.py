"""Revisit candidates, verification gates and the drift gate (runtime/graph/revisits.py).

Synthetic scenes: a textured wall with relief seen by two pinhole cameras; keypoints are exact
projections plus pixel noise, depths are the true z-depths plus relative noise.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from runtime.config_io import config_from_dict, config_to_dict
from runtime.errors import ConfigError
from runtime.geometry import make_pose, so3_exp
from runtime.geometry.se3 import se3_inverse
from runtime.graph import GraphConfig, GraphError
from runtime.graph.revisits import (
    RevisitConfig,
    RevisitStats,
    RevisitView,
    chain_drift_sigma,
    drift_gate,
    group_position_sigma,
    pair_covariances,
    revisit_candidates,
    revisit_pose_sigma,
    verify_revisit,
)

CFG = RevisitConfig()
W, H = 640, 480
K = np.array([[400.0, 0.0, 319.5], [0.0, 400.0, 239.5], [0.0, 0.0, 1.0]])
T_WSa = np.eye(4)
T_WSb = make_pose(so3_exp(np.array([0.02, math.radians(15.0), 0.01])), np.array([-0.8, 0.2, -0.5]))
SIGMA_SMALL = np.array([0.05, 0.05, 0.05, 0.01, 0.01, 0.01])


def wall(rng: np.random.Generator, n: int, half_w: float = 3.0, half_h: float = 2.2) -> np.ndarray:
    """(n,3) points on a wall with relief in front of camera a (world = S_a)."""
    x = rng.uniform(-half_w, half_w, n)
    y = rng.uniform(-half_h, half_h, n)
    z = 4.0 + 0.4 * np.sin(1.3 * x) * np.cos(0.9 * y)
    return np.column_stack([x, y, z])


def project(T_WS: np.ndarray, P_W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(uv, z) of world points in camera S."""
    P = (P_W - T_WS[:3, 3]) @ T_WS[:3, :3]
    uv = P @ K.T
    return uv[:, :2] / uv[:, 2:], P[:, 2]


def inside(uv: np.ndarray, z: np.ndarray) -> np.ndarray:
    return (z > 0) & (uv[:, 0] > 1) & (uv[:, 0] < W - 2) & (uv[:, 1] > 1) & (uv[:, 1] < H - 2)


def scene(seed: int = 0, n: int = 400, outlier_frac: float = 0.2, P_Wa: np.ndarray | None = None,
          P_Wb: np.ndarray | None = None, T_WSb_true: np.ndarray = T_WSb, px_noise: float = 0.3,
          depth_noise: float = 0.01, nan_frac: float = 0.0):
    """Views a and b and matches (idx_a, idx_b); point i of P_Wa looks like point i of P_Wb.

    Returns (a, b, (idx_a, idx_b), correct) where correct[k] tells whether match k is a true pairing.
    """
    rng = np.random.default_rng(seed)
    P_Wa = wall(rng, n) if P_Wa is None else P_Wa
    P_Wb = P_Wa if P_Wb is None else P_Wb
    uv_a, z_a = project(T_WSa, P_Wa)
    uv_b, z_b = project(T_WSb_true, P_Wb)
    vis = np.flatnonzero(inside(uv_a, z_a) & inside(uv_b, z_b))
    m = len(vis)
    kp_a = uv_a[vis] + px_noise * rng.standard_normal((m, 2))
    d_a = z_a[vis] * (1 + depth_noise * rng.standard_normal(m))
    perm = rng.permutation(m)                       # b's keypoint order differs from a's
    kp_b = np.empty((m, 2))
    d_b = np.empty(m)
    kp_b[perm] = uv_b[vis] + px_noise * rng.standard_normal((m, 2))
    d_b[perm] = z_b[vis] * (1 + depth_noise * rng.standard_normal(m))
    d_a[rng.random(m) < nan_frac] = np.nan
    d_b[rng.random(m) < nan_frac] = np.nan
    idx_a = np.arange(m)
    idx_b = perm.copy()
    bad = rng.random(m) < outlier_frac
    idx_b[bad] = rng.permutation(idx_b[bad])        # wrong partners (a derangement is not needed)
    correct = idx_b == perm
    a = RevisitView(K, kp_a, d_a, (W, H))
    b = RevisitView(K, kp_b, d_b, (W, H))
    return a, b, (idx_a, idx_b), correct


def T_SaSb_true(T_WSb_true: np.ndarray = T_WSb) -> np.ndarray:
    return se3_inverse(T_WSa) @ T_WSb_true


def small_drift(T: np.ndarray) -> np.ndarray:
    return T @ make_pose(so3_exp(np.array([0.0, 0.003, -0.002])), np.array([0.03, -0.02, 0.01]))


def test_config_holds_the_paper_numbers_and_round_trips():
    c = RevisitConfig()
    assert (c.candidate_radius_m, c.min_time_gap_s) == (8.0, 5.0)
    assert (c.pnp.min_matches, c.pnp.min_inliers, c.pnp.min_inlier_fraction, c.pnp.reprojection_px) == (
        50, 30, 0.25, 2.0)
    assert (c.max_depth_rel_error, c.innovation_sigmas, c.max_correspondences, c.scale_sigma) == (
        0.2, 3.0, 80, 0.03)
    assert c.scale_sigma == GraphConfig().revisit_scale_sigma
    d = config_to_dict(c)
    d["pnp"]["min_inliers"] = 40
    c2 = config_from_dict(RevisitConfig, d)
    assert c2.pnp.min_inliers == 40 and c2.min_coverage_cells == c.min_coverage_cells
    assert c2.view_scales == c.view_scales == (1.0, 0.7, 0.5)


@pytest.mark.parametrize("scales", [[0.7, 0.5], [1.0, 0.5, 0.7], [1.0, 0.5, 0.5], [1.0, 0.0], [],
                                    [1.0, float("nan")]])
def test_view_scales_must_be_a_decreasing_pyramid_from_full_resolution(scales):
    with pytest.raises(ConfigError, match="view_scales"):
        config_from_dict(RevisitConfig, {"view_scales": scales})
    assert config_from_dict(RevisitConfig, {"view_scales": [1.0]}).view_scales == (1.0,)


def test_candidates_respect_radius_time_gap_order_and_limit():
    ids = [0, 1, 2, 3, 4, 5, 6, 7]
    t_s = [0.0, 2.0, 10.0, 15.5, 15.0, 5.0, 20.0, 25.0]
    pos = np.array([[3.0, 0, 0], [0, 9.0, 0], [0, 0, 1.0], [0.5, 0, 0], [0, 7.9, 0], [0, 0, -8.0],
                    [0.0, 0, 0], [0.2, 0, 0]])
    t_ns = [int(round(s * 1e9)) for s in t_s]
    # 1: 9 m away; 3: only 4.5 s older; 7: newer; 6: itself. 4 is exactly 5 s and 5 exactly 8 m: kept.
    assert revisit_candidates(ids, t_ns, pos, 6, RevisitConfig(max_candidates=10)) == [2, 0, 4, 5]
    assert revisit_candidates(ids, t_ns, pos, 6, CFG) == [2, 0, 4]
    assert revisit_candidates(ids, t_ns, pos, 0, CFG) == []
    with pytest.raises(GraphError):
        revisit_candidates(ids, t_ns, pos, 99, CFG)


def test_true_revisit_is_accepted_and_its_correspondences_agree_with_the_truth():
    a, b, m, correct = scene(seed=1, nan_frac=0.05)
    assert 0.15 < 1 - correct.mean() < 0.25 and len(correct) > 150
    T_true = T_SaSb_true()
    res = verify_revisit(a, b, m, small_drift(T_true), SIGMA_SMALL, CFG)
    assert res.accepted, res.reason
    assert res.stage == "accepted"
    assert res.inlier_fraction > 0.6
    assert len(res.p_a) == len(res.p_b) == 80
    # Each pair is the same wall point: p_a = T_SaSb p_b up to the 1 % depth noise.
    err = np.linalg.norm(res.p_a - (res.p_b @ T_true[:3, :3].T + T_true[:3, 3]), axis=1)
    assert err.max() < 0.25 and np.median(err) < 0.08
    # Points in S_a lie on the wall (world = S_a): z = 4 + relief.
    relief = 4.0 + 0.4 * np.sin(1.3 * res.p_a[:, 0]) * np.cos(0.9 * res.p_a[:, 1])
    assert np.abs(res.p_a[:, 2] - relief).max() < 0.2
    # Spread over b's image: the 80 span the covered cells, not one region.
    uv = res.p_b @ K.T
    uv = uv[:, :2] / uv[:, 2:]
    cells = {(int(u * 4 // W), int(v * 4 // H)) for u, v in uv}
    assert len(cells) >= 10
    assert abs(res.kappa) < 0.01 and res.scale_sigma == 0.03
    assert np.all(np.abs(res.innovation) <= res.innovation_bound)
    assert not res.admit_points                   # a few cm of drift: the revisit only links scale


def test_scale_ratio_sign_follows_the_scale_link_convention():
    a, b, m, _ = scene(seed=2)
    b.depth_at_kpts = b.depth_at_kpts * 1.1       # b's depths 10 % too long: lambda_b - lambda_a = -log 1.1
    res = verify_revisit(a, b, m, small_drift(T_SaSb_true()), SIGMA_SMALL, CFG)
    assert res.accepted, res.reason
    assert res.log_depth_ratio == pytest.approx(math.log(1.1), abs=0.01)
    assert res.kappa == pytest.approx(-math.log(1.1), abs=0.01)
    assert res.depth_rel_error == pytest.approx(1 - 1 / 1.1, abs=0.01)


@pytest.mark.parametrize("offset_m", [5.0, 1.0])
def test_false_revisit_on_an_identical_wall_elsewhere_fails_the_innovation_test(offset_m):
    rng = np.random.default_rng(3)
    P_A = wall(rng, 400)
    shift = np.array([offset_m, 0.0, 0.0])              # a second, identical wall to the side
    T_WSb_true = make_pose(np.eye(3), shift) @ T_WSb    # b truly faces the copy as a would face A
    a, b, m, _ = scene(seed=3, P_Wa=P_A, P_Wb=P_A + shift, T_WSb_true=T_WSb_true)
    T_pred = small_drift(T_SaSb_true(T_WSb_true))       # odometry: b is offset_m from where PnP puts it
    res = verify_revisit(a, b, m, T_pred, SIGMA_SMALL, CFG)
    assert not res.accepted and res.stage == "innovation", res.reason
    assert res.n_inliers >= 200                         # the matches are self-consistent ...
    assert res.depth_rel_error < 0.05                   # ... and agree with b's depths
    assert res.innovation is not None and np.abs(res.innovation[:3]).max() > 0.9 * offset_m
    assert len(res.p_a) == 0 and math.isnan(res.kappa)
    # The same matches pass when the prediction is this uncertain: the test is relative to drift.
    res = verify_revisit(a, b, m, T_pred, np.array([2 * offset_m] * 3 + [0.5] * 3), CFG)
    assert res.accepted and res.admit_points


def test_wrong_depths_fail_depth_agreement():
    a, b, m, _ = scene(seed=4)
    b.depth_at_kpts = b.depth_at_kpts * 1.5
    res = verify_revisit(a, b, m, small_drift(T_SaSb_true()), SIGMA_SMALL, CFG)
    assert not res.accepted and res.stage == "depth_agreement", res.reason
    assert res.depth_rel_error == pytest.approx(1 / 3, abs=0.02)


def test_clustered_inliers_fail_coverage():
    rng = np.random.default_rng(5)
    P = wall(rng, 150, half_w=0.35, half_h=0.35)          # one small patch: about 70 px wide
    a, b, m, _ = scene(seed=5, P_Wa=P, outlier_frac=0.0, px_noise=0.1)
    res = verify_revisit(a, b, m, small_drift(T_SaSb_true()), SIGMA_SMALL, CFG)
    assert res.n_matches >= 100 and res.n_inliers >= 30
    assert not res.accepted and res.stage == "coverage", res.reason
    assert 1 <= res.coverage_cells < CFG.min_coverage_cells


def test_too_few_matches_and_pnp_failures_are_refused_with_their_stage():
    a, b, (ia, ib), _ = scene(seed=6)
    res = verify_revisit(a, b, (ia[:40], ib[:40]), T_SaSb_true(), SIGMA_SMALL, CFG)
    assert not res.accepted and res.stage == "matches" and "40 < 50" in res.reason
    rng = np.random.default_rng(6)
    res = verify_revisit(a, b, (ia, rng.permutation(ib)), T_SaSb_true(), SIGMA_SMALL, CFG)
    assert not res.accepted and res.stage == "pnp"
    stats = RevisitStats()
    for r in (res, verify_revisit(a, b, (ia, ib), T_SaSb_true(), SIGMA_SMALL, CFG)):
        stats.record(r)
    assert (stats.attempts, stats.accepted, stats.rejected["pnp"]) == (2, 1, 1)
    with pytest.raises(GraphError):
        verify_revisit(a, b, (ia, ib[:-1]), T_SaSb_true(), SIGMA_SMALL, CFG)
    with pytest.raises(GraphError):
        verify_revisit(a, b, (ia, ib), T_SaSb_true(), SIGMA_SMALL[:3], CFG)


def test_chain_drift_matches_the_closed_form_of_a_straight_chain():
    g = GraphConfig()
    s_t, s_r = 0.02, math.radians(0.5)                   # drift model floors at 1 m edges
    n = 7
    Z = make_pose(np.eye(3), np.array([1.0, 0.0, 0.0]))
    sig = chain_drift_sigma([Z] * n, g)
    d = np.arange(n)                                     # rotation drift i edges before b
    lateral = math.sqrt(np.sum(s_t**2 + (d * s_r) ** 2))
    np.testing.assert_allclose(sig, [math.sqrt(n) * s_t, lateral, lateral] + [math.sqrt(n) * s_r] * 3)
    assert np.all(chain_drift_sigma([], g) == 0)


def test_group_position_sigma_is_one_point_worth_of_the_pair_covariances():
    p = np.array([[0.0, 0.0, 5.0]] * 7)                 # C = diag(0.1^2, 0.1^2, 0.5^2) for both points
    expected = math.sqrt(2) * np.array([0.1, 0.1, 0.5])
    paper = GraphConfig(point_sigma_min_m=0.10)                 # the paper's floor; the default is 5 cm
    np.testing.assert_allclose(group_position_sigma(p, p, np.eye(3), paper), expected)
    np.testing.assert_allclose(group_position_sigma(p, p, np.eye(3)),
                               math.sqrt(2) * np.array([0.05, 0.05, 0.5]))
    rng = np.random.default_rng(7)
    T = T_SaSb_true()
    p_b = wall(rng, 60) @ np.diag([0.8, 0.8, 1.0])
    p_a = p_b @ T[:3, :3].T + T[:3, 3]
    s = group_position_sigma(p_a, p_b, T[:3, :3])
    np.testing.assert_allclose(group_position_sigma(np.vstack([p_a] * 3), np.vstack([p_b] * 3), T[:3, :3]), s)
    S = pair_covariances(p_a, p_b, T[:3, :3])
    assert np.all(s >= math.sqrt(2) * GraphConfig().point_sigma_min_m - 1e-12)   # both points floored
    assert np.all(s <= np.sqrt(S.diagonal(axis1=1, axis2=2).max(axis=0)))


def test_revisit_pose_sigma_averages_independent_pairs_and_adds_the_depth_scale():
    rng = np.random.default_rng(8)
    T = T_SaSb_true()
    p_b = wall(rng, 60) @ np.diag([0.8, 0.8, 1.0])
    p_a = p_b @ T[:3, :3].T + T[:3, 3]
    s0 = revisit_pose_sigma(p_a, p_b, T, 0.0)
    np.testing.assert_allclose(revisit_pose_sigma(np.vstack([p_a] * 4), np.vstack([p_b] * 4), T, 0.0), s0 / 2)
    # Knowing the rotation can only shrink the translation sigma: (sum_k Sigma_k^-1)^-1 bounds it below.
    S = pair_covariances(p_a, p_b, T[:3, :3])
    assert np.all(s0[:3] >= np.sqrt(np.diag(np.linalg.inv(np.linalg.inv(S).sum(axis=0)))) - 1e-12)
    s1 = revisit_pose_sigma(p_a, p_b, T, 0.1)
    t_SbSa = se3_inverse(T)[:3, 3]
    np.testing.assert_allclose(s1[:3] ** 2 - s0[:3] ** 2, (0.1 * t_SbSa) ** 2, atol=1e-12)
    np.testing.assert_allclose(s1[3:], s0[3:])
    with pytest.raises(GraphError):
        revisit_pose_sigma(p_a[:2], p_b[:2], T, 0.1)


def test_drift_gate_opens_only_when_drift_exceeds_the_revisit_uncertainty():
    a, b, m, _ = scene(seed=8)
    res = verify_revisit(a, b, m, small_drift(T_SaSb_true()), SIGMA_SMALL, CFG)
    assert res.accepted and res.revisit_sigma is not None
    ps = res.revisit_sigma[:3]
    # the measured relative pose: ~80 ray-aligned pairs, plus a's 10 % depth scale over the ~1 m baseline
    t_ab = np.linalg.norm(T_SaSb_true()[:3, 3])
    assert 0.1 * t_ab / 2 < np.linalg.norm(ps) < 0.1 * t_ab * 2
    np.testing.assert_allclose(ps, revisit_pose_sigma(res.p_a, res.p_b, se3_inverse(
        se3_inverse(T_SaSb_true())), CFG.innovation_scale_sigma)[:3], rtol=0.2)
    step = make_pose(so3_exp(np.array([0.0, 0.1, 0.0])), np.array([1.0, 0.0, 0.0]))
    short = chain_drift_sigma([step] * 3)                # 3 m of odometry: a few cm
    long = chain_drift_sigma([step] * 40)                # 40 m around a loop: about a metre
    assert not drift_gate(short, ps) and drift_gate(long, ps)
    assert not res.admit_points
    assert verify_revisit(a, b, m, small_drift(T_SaSb_true()), long, CFG).admit_points
    r = np.linalg.norm(ps)
    assert not drift_gate(np.r_[[0.99 * r / math.sqrt(3)] * 3, [1.0] * 3], ps)   # rotation is not gated
    assert drift_gate(np.array([1.01 * r / math.sqrt(3)] * 3), ps)
    res_long = verify_revisit(a, b, m, small_drift(T_SaSb_true()), long, CFG)
    assert res_long.accepted and res_long.admit_points
