"""SubmapGraph.solve against independent expectations: synthetic ground-truth graphs (poses, scales,
points) whose factors are generated from the truth, then perturbed."""
from __future__ import annotations

import copy
import json
import math

import numpy as np
import pytest
from graph_synth import R_BODY_CAM, corresponding_points, loop_poses, rz

from runtime.geometry import make_pose, se3_exp, se3_inverse, so3_exp
from runtime.graph import GraphConfig, GraphError, SubmapGraph, huber_rho, huber_weight

EZ = np.array([0.0, 0.0, 1.0])
PAPER = GraphConfig(gauge_lambda_free=False)
"""The paper's gauge: the first node fixes its pose and lambda_0 (the solver tests below)."""


def yaw_of(R: np.ndarray) -> float:
    """Yaw (rad) of a rotation about z."""
    return math.atan2(R[1, 0], R[0, 0])


def truth_poses(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(n,4,4) T_MS along a curved, climbing path with non-zero roll/pitch, and lambdas (lambda_0 = 0)."""
    Ts = []
    for j in range(n):
        tilt = so3_exp(np.array([0.04 * math.sin(j), -0.03 * math.cos(j), 0.0]))
        R = rz(0.15 * j) @ tilt @ R_BODY_CAM
        Ts.append(make_pose(R, np.array([0.4 * j, 0.3 * math.sin(0.5 * j), 1.0 + 0.05 * j])))
    lams = np.concatenate([[0.0], rng.normal(0.0, 0.05, n - 1)])
    return np.array(Ts), lams


def build(n: int, seed: int, k: int = 40, cfg: GraphConfig | None = None, odo_noise: float = 0.0,
          point_noise: float = 0.0, scale_noise: float = 0.0, points: bool = True, links: bool = True):
    """A chain graph at the true states with factors from the truth (plus optional noise)."""
    rng = np.random.default_rng(seed)
    Ts, lams = truth_poses(n, rng)
    g = SubmapGraph(cfg)
    for j in range(n):
        g.add_node(j, Ts[j], lams[j])
    for a in range(n - 1):
        b = a + 1
        xi = np.concatenate([rng.normal(0, odo_noise, 3), rng.normal(0, odo_noise / 4, 3)])
        g.add_odometry(a, b, se3_inverse(Ts[a]) @ Ts[b] @ se3_exp(xi))
        if points:
            pa, pb = corresponding_points(Ts[a], lams[a], Ts[b], lams[b], k, rng)
            g.add_points(a, b, pa + rng.normal(0, point_noise, pa.shape),
                         pb + rng.normal(0, point_noise, pb.shape), adjacent=True)
        if links:
            g.add_scale_link(a, b, lams[b] - lams[a] + rng.normal(0, scale_noise), 0.03)
    return g, Ts, lams, rng


def perturb(g: SubmapGraph, rng: np.random.Generator, st: float = 0.2, syaw: float = math.radians(3),
            slam: float = 0.05) -> SubmapGraph:
    """A copy of g whose free nodes are moved in translation, yaw and lambda (roll/pitch untouched)."""
    out = SubmapGraph(g.cfg)
    for j in g.node_ids:
        s = g.node_state(j)
        T = s.T_MS.copy()
        lam = s.lam
        if not s.fixed:
            T[:3, :3] = rz(rng.normal(0, syaw)) @ T[:3, :3]
            T[:3, 3] += rng.normal(0, st, 3)
            lam += rng.normal(0, slam)
        out.add_node(j, T, lam)
    out.odometry = list(g.odometry)
    out.point_groups = list(g.point_groups)
    out.scale_links = list(g.scale_links)
    return out


def errors(g: SubmapGraph, Ts: np.ndarray, lams: np.ndarray) -> tuple[float, float, float]:
    """Max translation (m), yaw (rad) and lambda errors of all nodes against the truth."""
    et, ey, el = 0.0, 0.0, 0.0
    for j in g.node_ids:
        s = g.node_state(j)
        et = max(et, float(np.linalg.norm(s.T_MS[:3, 3] - Ts[j][:3, 3])))
        ey = max(ey, abs(yaw_of(s.T_MS[:3, :3] @ Ts[j][:3, :3].T)))
        el = max(el, abs(s.lam - lams[j]))
    return et, ey, el


def test_recovers_a_perturbed_synthetic_graph():
    g, Ts, lams, rng = build(8, seed=1, odo_noise=0.002, point_noise=0.002, scale_noise=0.005, cfg=PAPER)
    p = perturb(g, rng)
    before = errors(p, Ts, lams)
    assert before[0] > 0.2 and before[1] > math.radians(2) and before[2] > 0.03
    rep = p.solve()
    assert rep.iterations <= 8 and rep.cost_after < 0.05 * rep.cost_before
    et, ey, el = errors(p, Ts, lams)
    assert et < 0.03 and ey < math.radians(0.2) and el < 0.02
    assert sorted(rep.changed) == list(range(1, 8))


def test_gauge_and_gravity_directions_stay_fixed():
    g, Ts, lams, rng = build(8, seed=2, odo_noise=0.002, cfg=PAPER)
    p = perturb(g, rng)
    before = {j: p.node_state(j) for j in p.node_ids}
    p.solve()
    p.solve()
    g0 = p.node_state(0)
    assert np.array_equal(g0.T_MS, before[0].T_MS) and g0.lam == before[0].lam and g0.fixed
    for j in p.node_ids:
        R0, R1 = before[j].T_MS[:3, :3], p.node_state(j).T_MS[:3, :3]
        np.testing.assert_allclose(R1.T @ EZ, R0.T @ EZ, rtol=0, atol=1e-12)
        np.testing.assert_allclose(R1.T @ R1, np.eye(3), atol=1e-12)


def test_rotation_updates_are_pure_yaw():
    g, Ts, lams, _ = build(6, seed=3)
    p = SubmapGraph(g.cfg)
    for j in g.node_ids:
        T = g.node_state(j).T_MS.copy()
        if j == 3:
            T[:3, :3] = rz(math.radians(4.0)) @ T[:3, :3]
        p.add_node(j, T, g.node_state(j).lam)
    p.odometry, p.point_groups, p.scale_links = g.odometry, g.point_groups, g.scale_links
    R_before = p.node_state(3).T_MS[:3, :3]
    p.solve()
    dR = p.node_state(3).T_MS[:3, :3] @ R_before.T
    np.testing.assert_allclose(dR[2], EZ, atol=1e-12)
    np.testing.assert_allclose(dR[:, 2], EZ, atol=1e-12)
    assert math.degrees(yaw_of(dR)) == pytest.approx(-4.0, abs=0.01)
    # exact factors, but every lambda's prior pulls it towards 0, which the points turn into a small yaw
    assert errors(p, Ts, lams)[1] < math.radians(0.02)


def test_huber_weight_is_rho_prime_over_r():
    h = 1e-6
    for r, expected in ((1.0, 1.0), (4.0, 0.5)):
        rho_prime = (huber_rho(r + h) - huber_rho(r - h)) / (2 * h)
        assert float(huber_weight(r)) == pytest.approx(expected)
        assert float(huber_weight(r)) == pytest.approx(rho_prime / r, rel=1e-8)
    assert float(huber_rho(1.0)) == 0.5 and float(huber_rho(4.0)) == 6.0      # r^2/2 and 2r - 2


def test_objective_is_the_exact_huber_sum():
    """E from the graph equals the paper's sum, computed by hand on a two-node graph."""
    T0 = make_pose(np.eye(3), np.zeros(3))
    T1 = make_pose(rz(0.3), np.array([1.0, 0.0, 0.0]))
    g = SubmapGraph()
    g.add_node(0, T0, 0.0)
    g.add_node(1, T1, 0.15)
    g.add_odometry(0, 1, se3_inverse(T0) @ T1)                      # zero residual
    g.add_scale_link(0, 1, -0.5, 0.03)                               # r = 0.65 / 0.03: linear branch
    expected = (0.15 / 0.10) ** 2 / 2 + (2 * (0.65 / 0.03) - 2)
    assert g.objective() == pytest.approx(expected, rel=1e-12)


def test_outlier_point_group_moves_huber_less_than_quadratic():
    results = {}
    for k in (2.0, math.inf):
        g, Ts, lams, rng = build(8, seed=4, odo_noise=0.001, cfg=GraphConfig(huber_threshold=k))
        pa, pb = corresponding_points(Ts[1], lams[1], Ts[6], lams[6], 80, rng)
        g.add_points(1, 6, pa, pb + np.array([1.5, 0.0, 0.0]), adjacent=False)    # wrong matches
        g.solve(max_iterations=30)
        results[k] = errors(g, Ts, lams)[0]
    assert results[math.inf] > 0.05
    assert results[2.0] < 0.5 * results[math.inf]


def test_eviction_refixes_the_gauge_at_the_current_state():
    g, Ts, lams, rng = build(6, seed=5, odo_noise=0.002, cfg=PAPER)
    p = perturb(g, rng)
    p.solve()
    s2 = p.node_state(2)
    assert p.evict(1) == [0, 1]
    assert p.gauge == 2 and p.node_ids == [2, 3, 4, 5] and p.node_state(2).fixed
    assert all(f.a >= 2 and f.b >= 2 for f in p.odometry + p.point_groups + p.scale_links)
    assert len(p.odometry) == 3 and len(p.point_groups) == 3 and len(p.scale_links) == 3
    # a new node tied only by odometry: its lambda is set by the prior alone, still centred on the first
    # node's lambda_0 (the metric scale), not on the new gauge's lambda_2
    assert p.lam_ref == lams[0] and abs(s2.lam - lams[0]) > 0.01
    T6 = p.node_state(5).T_MS @ make_pose(np.eye(3), np.array([0.3, 0.0, 0.0]))
    p.add_node(6, make_pose(rz(0.05) @ T6[:3, :3], T6[:3, 3] + 0.1), s2.lam + 0.3)
    p.add_odometry(5, 6, se3_inverse(p.node_state(5).T_MS) @ T6)
    rep = p.solve(max_iterations=20)
    assert 2 not in rep.changes
    now = p.node_state(2)
    assert np.array_equal(now.T_MS, s2.T_MS) and now.lam == s2.lam
    assert p.node_state(6).lam == pytest.approx(lams[0], abs=1e-5)
    assert p.as_dict()["gauge"] == 2 and p.as_dict()["lambda_ref"] == lams[0]


def test_evict_excess_keeps_the_newest_nodes():
    g, *_ = build(6, seed=6, cfg=GraphConfig(max_resident_nodes=4), points=False)
    assert g.evict_excess() == [0, 1]
    assert g.node_ids == [2, 3, 4, 5] and g.evict_excess() == []


def test_scale_link_chain_recovers_lambda_differences_with_a_weak_prior():
    kappas = [0.2, -0.1, 0.3, 0.25, -0.05]
    truth = np.concatenate([[0.0], np.cumsum(kappas)])
    for sigma_prior, close in ((1e3, True), (0.10, False)):
        g = SubmapGraph(GraphConfig(scale_prior_sigma=sigma_prior, gauge_lambda_free=False))
        Ts, _ = truth_poses(6, np.random.default_rng(7))
        for j in range(6):
            g.add_node(j, Ts[j], 0.0)
        for a, kappa in enumerate(kappas):
            g.add_odometry(a, a + 1, se3_inverse(Ts[a]) @ Ts[a + 1])
            g.add_scale_link(a, a + 1, kappa, 0.03)
        g.solve(max_iterations=20)
        lam = np.array([g.node_state(j).lam for j in range(6)])
        if close:
            np.testing.assert_allclose(np.diff(lam), kappas, atol=1e-5)
            np.testing.assert_allclose(lam, truth, atol=1e-4)
        else:                                    # the 0.10 prior visibly pulls lambda towards lambda_0
            assert np.abs(lam - truth).max() > 0.01


def test_jacobian_and_gradient_match_finite_differences():
    g, Ts, lams, rng = build(5, seed=8, k=10, odo_noise=0.002)
    p = perturb(g, rng, st=0.3)
    pa, pb = corresponding_points(Ts[0], lams[0], Ts[3], lams[3], 10, rng)
    p.add_points(0, 3, pa, pb + 1.0, adjacent=False)          # Huber's linear branch is active
    prob = p.problem()
    x = rng.normal(0, 0.02, prob.n_params)
    J = prob.jacobian(x).toarray()
    f = prob.residual(x)
    h = 1e-6
    Jn = np.stack([(prob.residual(x + h * e) - prob.residual(x - h * e)) / (2 * h)
                   for e in np.eye(len(x))], axis=1)
    np.testing.assert_allclose(J, Jn, atol=2e-4 * np.abs(Jn).max())
    rho = prob.loss(f * f)
    assert np.any(rho[1] < 1.0)
    grad = J.T @ (rho[1] * f)                 # scipy's gradient with the block loss
    grad_n = np.array([(prob.cost(x + h * e) - prob.cost(x - h * e)) / (2 * h) for e in np.eye(len(x))])
    np.testing.assert_allclose(grad, grad_n, atol=1e-4 * np.abs(grad_n).max())
    assert 0.5 * rho[0].sum() == pytest.approx(prob.cost(x), rel=1e-12)


def test_iteration_cap_report_and_manifest():
    g, Ts, lams, rng = build(6, seed=9, odo_noise=0.002)
    p = perturb(g, rng, st=0.5)
    q = copy.deepcopy(p)
    rep1 = p.solve(max_iterations=1)
    assert rep1.iterations <= 1 and rep1.cost_after <= rep1.cost_before
    before = {j: q.node_state(j) for j in q.node_ids}
    rep = q.solve()
    assert 1 <= rep.iterations <= 8 and rep.jacobians >= 1 and rep.time_s > 0
    for j, c in rep.changes.items():
        b, a = before[j], q.node_state(j)
        np.testing.assert_allclose(c.dt, a.T_MS[:3, 3] - b.T_MS[:3, 3], atol=1e-12)
        assert c.dyaw == pytest.approx(yaw_of(a.T_MS[:3, :3] @ b.T_MS[:3, :3].T), abs=1e-12)
        assert c.dlam == pytest.approx(a.lam - b.lam, abs=1e-12)
    d = q.as_dict()
    json.dumps(d)
    json.dumps(rep.as_dict())
    assert [n["id"] for n in d["nodes"]] == list(range(6)) and d["nodes"][0]["fixed"]
    assert len(d["odometry"]) == 5 and d["point_groups"][0]["n"] == 40 and "p_a" not in d["point_groups"][0]


def test_an_anchor_pulls_the_drifted_chain_and_stays_fixed():
    """A loop of 16 submaps: nodes 4..15 are resident (4 the gauge, at the truth) and placed by odometry
    that drifts 3 cm per edge sideways; node 0, evicted long ago, comes back as an anchor at its true state,
    and a revisit point group 0-15 closes the loop: node 15 moves towards the truth (the group weighs as one
    point with ray-aligned sigmas, so part of the way), while the anchor and the gauge do not move."""
    rng = np.random.default_rng(21)
    n = 16
    Ts = loop_poses(n)
    bias = make_pose(np.eye(3), np.array([0.03, 0.0, 0.0]))
    g = SubmapGraph()
    g.add_node(4, Ts[4], 0.0)
    T = Ts[4]
    for b in range(5, n):
        Z = se3_inverse(Ts[b - 1]) @ Ts[b] @ bias
        T = T @ Z
        g.add_node(b, T, 0.0)
        g.add_odometry(b - 1, b, Z)
    with pytest.raises(GraphError, match="older than the gauge"):
        g.add_anchor(99, Ts[5], 0.0)
    g.add_anchor(0, Ts[0], 0.0)
    with pytest.raises(GraphError, match="already"):
        g.add_anchor(0, Ts[0], 0.0)
    assert g.anchor_ids == [0] and len(g) == n - 4 and g.node_state(0).fixed and g.is_fixed(4)
    last = n - 1
    before = float(np.linalg.norm(g.node_state(last).T_MS[:3, 3] - Ts[last][:3, 3]))
    unclosed = copy.deepcopy(g)
    unclosed.solve(max_iterations=20)
    pa, pb = corresponding_points(Ts[0], 0.0, Ts[last], 0.0, 80, rng)
    g.add_points(0, last, pa, pb, adjacent=False)
    rep = g.solve(max_iterations=20)
    after = float(np.linalg.norm(g.node_state(last).T_MS[:3, 3] - Ts[last][:3, 3]))
    stays = float(np.linalg.norm(unclosed.node_state(last).T_MS[:3, 3] - Ts[last][:3, 3]))
    assert before > 0.1 and stays == pytest.approx(before, abs=1e-9) and after < 0.85 * before
    assert 0 not in rep.changes and 4 not in rep.changes
    np.testing.assert_array_equal(g.node_state(0).T_MS, Ts[0])
    np.testing.assert_array_equal(g.node_state(4).T_MS, Ts[4])
    d = g.as_dict()
    assert d["nodes"][0]["id"] == 0 and d["nodes"][0]["anchor"] and not d["nodes"][1]["anchor"]
    # the anchor stays while a factor reaches it, and leaves with the last one
    assert g.evict(last - 1) == list(range(4, last)) and g.anchor_ids == [0] and g.gauge == last
    step = make_pose(np.eye(3), np.array([0.3, 0.0, 0.0]))
    g.add_node(n, g.node_state(last).T_MS @ step, 0.0)
    g.add_odometry(last, n, step)
    assert g.evict(last) == [last] and g.anchor_ids == [] and 0 not in g


def test_scale_reference_does_not_walk_with_the_gauge_over_evictions():
    """A long run whose true lambdas are all 0 (metric depths), tied by scale links with 0.03 noise, in a
    10-node window: each eviction hands the gauge to a node whose lambda carries its estimation error. The
    priors stay centred on lambda_0, so the evicted states stay near 0 (RMS 0.025-0.028 over seeds 11-13);
    centred on each new gauge's lambda they drift (measured: RMS 0.042-0.048 on seeds 11-13, 0.034-0.049
    over seeds 11-18)."""
    rng = np.random.default_rng(11)
    g = SubmapGraph(GraphConfig(max_resident_nodes=10))
    final: dict[int, float] = {}
    T = make_pose(np.eye(3), np.zeros(3))
    step = make_pose(np.eye(3), np.array([0.5, 0.0, 0.0]))
    for j in range(200):
        g.add_node(j, T, 0.0)
        if j:
            g.add_odometry(j - 1, j, step)
            g.add_scale_link(j - 1, j, rng.normal(0.0, 0.03), 0.03)
            g.solve(max_iterations=8)
        before = {k: g.node_state(k).lam for k in g.node_ids}
        for k in g.evict_excess():
            final[k] = before[k]
        T = T @ step
    lam = np.array(list(final.values()))
    assert len(lam) == 190
    assert np.sqrt(np.mean(lam ** 2)) < 0.035


def test_a_free_gauge_lambda_does_not_impose_the_first_submaps_depth_error():
    """The first submap's depths 12 % short (lambda*_0 = 0.12, as measured on V1_02's first window), the
    others right; scale links from the truth. With the paper's gauge (lambda_0 fixed at 0) the links carry
    the error to every neighbour; with the gauge's lambda free under the same prior the level is the
    priors' consensus. Both equal the closed-form least squares of the priors and links."""
    n = 10
    truth = np.zeros(n)
    truth[0] = 0.12
    Ts, _ = truth_poses(n, np.random.default_rng(3))
    out = {}
    for free in (False, True):
        g = SubmapGraph(GraphConfig(gauge_lambda_free=free))
        for j in range(n):
            g.add_node(j, Ts[j], 0.0)
        for a in range(n - 1):
            g.add_odometry(a, a + 1, se3_inverse(Ts[a]) @ Ts[a + 1])
            g.add_scale_link(a, a + 1, truth[a + 1] - truth[a], 0.03)
        rep = g.solve(max_iterations=20)
        out[free] = np.array([g.node_state(j).lam for j in range(n)])
        assert np.array_equal(g.node_state(0).T_MS, Ts[0]) and g.node_state(0).fixed   # the pose gauge
        assert (0 in rep.changes) == free
    for free in (False, True):     # the lambdas' own least-squares problem (priors and links), closed form
        A = [np.eye(n)[j] / 0.10 for j in range(0 if free else 1, n)]
        b = [0.0] * len(A)
        for a in range(n - 1):
            A.append((np.eye(n)[a + 1] - np.eye(n)[a]) / 0.03)
            b.append((truth[a + 1] - truth[a]) / 0.03)
        if not free:
            A.append(np.eye(n)[0] * 1e6)
            b.append(0.0)
        np.testing.assert_allclose(out[free], np.linalg.lstsq(np.array(A), np.array(b), rcond=None)[0],
                                   atol=5e-5)
    err = {free: np.abs(out[free] - truth) for free in (False, True)}
    assert err[True].max() < 0.04
    assert out[False][0] == 0.0 and err[False][1] > 0.08                 # the first neighbour inherits it
    assert err[False].mean() > 1.5 * err[True].mean()
