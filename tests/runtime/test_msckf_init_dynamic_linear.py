"""The dynamic initializer's linear solve alone, on noise-free synthetic windows with a known truth."""

from __future__ import annotations

import numpy as np
import pytest

from runtime.geometry import so3_exp
from runtime.msckf.init_dynamic_linear import (
    LinearSolution,
    in_front_of_first_camera,
    min_quadratic_on_sphere,
    solve_linear,
    states_in_gravity_frame,
)
from tests.runtime.test_msckf_init_dynamic import G0, R_IC, T_IC

P_IC = T_IC[:3, 3]


def synthetic_window(seed: int, n_feat: int = 30, far_feature: bool = False) -> dict:
    """A K = 6 keyframe window in I0: rotations, preintegration, features and exact observations."""
    rng = np.random.default_rng(seed)
    K = 6
    R_0k = np.stack([np.eye(3)] + [so3_exp(rng.normal(0, 0.15, 3)) for _ in range(K - 1)])
    dt_0k = np.linspace(0.0, 2.0, K)
    v0 = rng.normal(0, 0.8, 3)
    g = G0 * so3_exp(rng.normal(0, 0.5, 3)) @ np.array([0.0, 0.0, -1.0])
    p_k = np.vstack([np.zeros(3), rng.uniform(-0.5, 0.5, (K - 1, 3))])
    # gravity-free displacement consistent with p_k = v0 t + g t^2 / 2 + dp_0k
    dp_0k = p_k - v0 * dt_0k[:, None] - 0.5 * g * dt_0k[:, None] ** 2
    # features 4..8 m in front of the first camera
    p_C0 = np.c_[rng.uniform(-2, 2, (n_feat, 2)), rng.uniform(4, 8, n_feat)]
    if far_feature:
        p_C0[-1] = [0.0, 0.0, 1e8]
    p_f = p_C0 @ R_IC.T + P_IC
    R_CI, p_CI = R_IC.T, -R_IC.T @ P_IC
    rows = []
    for k in range(K):
        p_C = (p_f - p_k[k]) @ R_0k[k] @ R_CI.T + p_CI
        for n in range(n_feat):
            rows.append((k, n, p_C[n, 0] / p_C[n, 2], p_C[n, 1] / p_C[n, 2]))
    obs = np.array(rows)
    return dict(obs=obs, R_0k=R_0k, dt_0k=dt_0k, dp_0k=dp_0k, v0=v0, g=g, p_f=p_f, p_k=p_k, n_feat=n_feat)


def solve(w: dict, **kw: float) -> LinearSolution:
    args = dict(gravity_mag=G0, min_features=8, max_feature_condition=1e8) | kw
    return solve_linear(w["obs"], w["n_feat"], w["R_0k"], w["dt_0k"], w["dp_0k"], R_IC, P_IC, **args)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_noise_free_window_is_recovered_exactly(seed: int) -> None:
    w = synthetic_window(seed)
    lin = solve(w)
    assert lin.n_good == w["n_feat"] and np.isfinite(lin.condition)
    np.testing.assert_allclose(lin.g_I0, w["g"], atol=1e-7)
    np.testing.assert_allclose(lin.v_I0, w["v0"], atol=1e-7)
    np.testing.assert_allclose(lin.p_f, w["p_f"], atol=1e-6)
    assert lin.cost < 1e-18


def test_feature_without_depth_information_is_left_out() -> None:
    w = synthetic_window(3, far_feature=True)
    lin = solve(w)
    assert lin.n_good == w["n_feat"] - 1
    assert np.all(np.isnan(lin.p_f[-1])) and np.all(np.isfinite(lin.p_f[:-1]))
    np.testing.assert_allclose(lin.g_I0, w["g"], atol=1e-6)
    np.testing.assert_allclose(lin.p_f[:-1], w["p_f"][:-1], atol=1e-5)


def test_too_few_features_with_depth_give_an_infinite_cost() -> None:
    w = synthetic_window(4)
    lin = solve(w, max_feature_condition=1.0)  # no 3x3 block is perfectly conditioned
    assert lin.n_good == 0 and lin.cost == np.inf and lin.condition == np.inf
    assert np.all(np.isnan(lin.p_f))


def test_states_in_gravity_frame_match_the_truth_up_to_yaw() -> None:
    w = synthetic_window(5)
    rng = np.random.default_rng(5)
    dv_0k = rng.normal(0, 1.0, (6, 3))
    dv_0k[0] = 0.0
    lin = LinearSolution(w["v0"], w["g"], w["p_f"], 0.0, 1.0, w["n_feat"])
    R_k, p_k, v_k, p_Of = states_in_gravity_frame(lin, w["R_0k"], w["dt_0k"], w["dp_0k"], dv_0k)
    R_OI0 = R_k[0]
    np.testing.assert_allclose(R_OI0 @ w["g"], [0.0, 0.0, -G0], atol=1e-12)
    np.testing.assert_allclose(R_OI0 @ R_OI0.T, np.eye(3), atol=1e-12)
    for k in range(6):
        np.testing.assert_allclose(R_k[k], R_OI0 @ w["R_0k"][k], atol=1e-12)
        np.testing.assert_allclose(p_k[k], R_OI0 @ w["p_k"][k], atol=1e-12)
        v_I0 = w["v0"] + w["g"] * w["dt_0k"][k] + dv_0k[k]  # velocity definition of preintegration
        np.testing.assert_allclose(v_k[k], R_OI0 @ v_I0, atol=1e-12)
    np.testing.assert_allclose(p_Of, w["p_f"] @ R_OI0.T, atol=1e-12)


def test_in_front_of_first_camera() -> None:
    # camera axis z_C expressed in I is R_IC[:, 2]; points 1 m in front, 1 m behind, unknown
    z_I = R_IC[:, 2]
    p_f = np.array([P_IC + z_I, P_IC - z_I, [np.nan] * 3, P_IC + 2 * z_I])
    mask, fraction = in_front_of_first_camera(p_f, R_IC, P_IC)
    np.testing.assert_array_equal(mask, [True, False, False, True])
    assert fraction == pytest.approx(2 / 3)


def test_min_quadratic_on_sphere_hard_case_matches_brute_force() -> None:
    # m orthogonal to the smallest eigenvector: the minimiser sits at lam = e0 (the "hard case")
    M = np.diag([1.0, 4.0, 9.0])
    m = np.array([0.0, 3.0, -2.0])
    g = min_quadratic_on_sphere(M, m, 9.81)
    assert np.linalg.norm(g) == pytest.approx(9.81, rel=1e-12)
    u = np.random.default_rng(1).standard_normal((200000, 3))
    u = 9.81 * u / np.linalg.norm(u, axis=1, keepdims=True)
    cost = np.einsum("ni,ij,nj->n", u, M, u) - 2 * u @ m
    assert g @ M @ g - 2 * g @ m <= cost.min() + 1e-9
    # closed form: g_i = m_i / (e_i - e0) for i > 0, the rest along the smallest eigenvector
    np.testing.assert_allclose(g[1:], [1.0, -0.25], atol=1e-12)
