"""The dynamic initializer's refinement: finite differences, Jacobian pattern, convergence, covariance."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse

from runtime.geometry import so3_exp, so3_log
from runtime.msckf.init_dynamic_config import DynamicInitConfig
from runtime.msckf.init_dynamic_preintegration import preintegrate_keyframes
from runtime.msckf.init_dynamic_refinement import WindowRefinement, newest_state_covariance
from runtime.msckf.init_dynamic_sparse_jacobian import group_columns, sparse_fd_jacobian
from runtime.msckf.init_dynamic_window import select_features
from tests.runtime.test_msckf_init_dynamic import CAM, G0, R_IC, T_IC, landmarks
from tests.runtime.test_msckf_init_dynamic_window import biased_window


def test_sparse_fd_jacobian_matches_the_analytic_one() -> None:
    # f_i(x) = sin(x_i) x_{i+1}^2 + exp(0.1 x_{i+2}), a banded Jacobian
    n = 12
    rng = np.random.default_rng(0)
    x = rng.normal(0, 1, n)

    def fun(z: np.ndarray) -> np.ndarray:
        return np.sin(z[:-2]) * z[1:-1] ** 2 + np.exp(0.1 * z[2:])

    J_true = np.zeros((n - 2, n))
    i = np.arange(n - 2)
    J_true[i, i] = np.cos(x[:-2]) * x[1:-1] ** 2
    J_true[i, i + 1] = 2 * np.sin(x[:-2]) * x[1:-1]
    J_true[i, i + 2] = 0.1 * np.exp(0.1 * x[2:])
    S = scipy.sparse.lil_matrix(J_true != 0)
    groups = group_columns(scipy.sparse.csc_matrix(S))
    assert groups.max() + 1 == 3  # a band of width 3 needs exactly 3 groups
    J = sparse_fd_jacobian(fun, x, S).toarray()
    np.testing.assert_allclose(J, J_true, atol=1e-8)


def test_group_columns_never_share_a_row() -> None:
    S = scipy.sparse.random(40, 30, density=0.1, random_state=1, format="csc")
    groups = group_columns(S)
    assert np.all(groups >= 0)
    pattern = S.toarray() != 0
    for g in np.unique(groups):
        assert pattern[:, groups == g].sum(axis=1).max() <= 1


@pytest.fixture(scope="module")
def window() -> dict:
    """A noise-free window with the true keyframe states in the z-up world W (= O, g = (0, 0, -g0))."""
    keyframes, (ti, gyro, accel), t_kf, motion = biased_window(np.zeros(3))
    imu = preintegrate_keyframes(ti, gyro, accel, t_kf, np.zeros(3), np.zeros(3), 1.6968e-4, 2.0e-3)
    ids, obs = select_features(keyframes, 3, 30)
    states = [motion.state(t * 1e-9) for t in t_kf]
    return dict(
        obs=obs, between=imu.between,
        R=np.stack([s[0] for s in states]), p=np.stack([s[1] for s in states]),
        v=np.stack([s[2] for s in states]), p_f=landmarks()[ids],
    )  # fmt: skip


def refinement(window: dict, **cfg: float) -> WindowRefinement:
    g_O = np.array([0.0, 0.0, -G0])
    return WindowRefinement(
        window["obs"], window["between"], g_O, np.zeros(3), np.zeros(3), R_IC, T_IC[:3, 3], CAM.fx,
        DynamicInitConfig(**cfg),
    )


def test_residuals_vanish_at_the_truth_and_the_pattern_covers_the_jacobian(window: dict) -> None:
    ref = refinement(window)
    K = len(window["between"]) + 1
    ref.R_hat = window["R"].copy()
    ref.p0_hat = window["p"][0].copy()
    x = np.concatenate(
        [np.c_[np.zeros((K, 3)), window["p"], window["v"]].ravel(), np.zeros(6), window["p_f"].ravel()]
    )
    r = ref.residuals(x)
    n_proj = 2 * window["obs"].shape[0]
    assert np.abs(r[:n_proj]).max() < 1e-6  # px: exact projections
    assert np.abs(r[n_proj:]).max() < 0.05  # whitened IMU terms: only 1 kHz discretisation left
    # dense central differences, one column at a time: nothing outside the declared pattern
    x = x + np.random.default_rng(0).normal(0, 1e-3, x.size)
    S = ref.sparsity().toarray() != 0
    assert S.shape == (r.size, x.size)
    J = np.zeros(S.shape)
    for j in range(x.size):
        e = np.zeros(x.size)
        e[j] = 1e-6
        J[:, j] = (ref.residuals(x + e) - ref.residuals(x - e)) / 2e-6
    assert np.abs(J[~S]).max() == 0.0
    np.testing.assert_allclose(sparse_fd_jacobian(ref.residuals, x, ref.sparsity()).toarray(), J, atol=1e-3)
    # the analytic Jacobian the solver uses, within the pattern (entries up to 1e4: the gauge rows)
    J_analytic = ref.jacobian(x)
    assert np.abs(J_analytic[~S]).max() == 0.0
    np.testing.assert_allclose(J_analytic, J, rtol=1e-5, atol=1e-3)


def test_the_analytic_jacobian_away_from_the_linearisation_point(window: dict) -> None:
    """At rotations far from R_hat (theta of 0.3 rad), biases away from the priors' centres and features
    moved by 20 cm, the analytic Jacobian still equals central differences."""
    ref = refinement(window)
    K = len(window["between"]) + 1
    rng = np.random.default_rng(5)
    ref.R_hat = window["R"].copy()
    ref.p0_hat = window["p"][0].copy()
    theta = rng.normal(0, 0.3, (K, 3))
    x = np.concatenate([np.c_[theta, window["p"], window["v"]].ravel(), rng.normal(0, 0.02, 6),
                        (window["p_f"] + rng.normal(0, 0.2, window["p_f"].shape)).ravel()])
    J_fd = np.zeros((ref.residuals(x).size, x.size))
    for j in range(x.size):
        e = np.zeros(x.size)
        e[j] = 1e-6
        J_fd[:, j] = (ref.residuals(x + e) - ref.residuals(x - e)) / 2e-6
    J = ref.jacobian(x)
    scale = np.abs(J_fd).max(axis=1, keepdims=True) + 1.0
    assert np.abs((J - J_fd) / scale).max() < 1e-5


@pytest.mark.parametrize("solver", ["lm", "scipy-fd"])
def test_refinement_returns_to_the_truth_from_a_perturbed_start(window: dict, solver: str) -> None:
    rng = np.random.default_rng(3)
    K = len(window["between"]) + 1
    # first position and yaw are the gauge: keep them, perturb everything else
    R0 = np.stack([window["R"][0]] + [R @ so3_exp(rng.normal(0, 0.01, 3)) for R in window["R"][1:]])
    p0 = window["p"] + np.vstack([np.zeros(3), rng.normal(0, 0.03, (K - 1, 3))])
    v0 = window["v"] + rng.normal(0, 0.05, (K, 3))
    f0 = window["p_f"] + rng.normal(0, 0.05, window["p_f"].shape)
    # 1e-10: scipy-fd converges in 33 evaluations (at 1e-12 not in 50); lm in 7-8 either way
    cfg = dict(mle_max_iterations=50, mle_tolerance=1e-10, mle_solver=solver)
    out = refinement(window, **cfg).run(R0, p0, v0, f0)
    assert out is not None
    # from 0.6 deg / 3 cm / 5 cm/s / 5 cm errors back to the truth (left: 1 kHz preintegration error)
    for k in range(K):
        assert np.linalg.norm(so3_log(out.R_OI[k].T @ window["R"][k])) < 1e-6
    np.testing.assert_allclose(out.p_OI, window["p"], atol=1e-5)
    np.testing.assert_allclose(out.v_OI, window["v"], atol=1e-5)
    np.testing.assert_allclose(out.bg, 0.0, atol=1e-6)
    np.testing.assert_allclose(out.ba, 0.0, atol=1e-5)
    assert out.rms_px < 1e-4 and out.n_evaluations > 2 and out.converged
    assert out.cov.shape == (15, 15) and np.all(np.linalg.eigvalsh(out.cov) > 0)
    # the same start with two evaluations: the solver stops on its budget, and says so
    cut = refinement(window, **{**cfg, "mle_max_iterations": 2}).run(R0, p0, v0, f0)
    assert cut is not None and cut.n_evaluations == 2 and not cut.converged


def test_newest_state_covariance_is_the_inflated_marginal() -> None:
    rng = np.random.default_rng(2)
    K, n_feat = 3, 2
    n = 9 * K + 6 + 3 * n_feat
    A = rng.normal(0, 1, (2 * n, n))
    info = A.T @ A
    inflation = (10.0, 1.0, 100.0, 10.0, 100.0)
    cov = newest_state_covariance(info, K, inflation)
    full = np.linalg.inv(info)
    idx = list(range(18, 27)) + list(range(27, 33))  # newest [theta, p, v], then [bg, ba]
    D = np.diag(np.sqrt(np.repeat(inflation, 3)))
    np.testing.assert_allclose(cov, D @ full[np.ix_(idx, idx)] @ D, rtol=1e-6, atol=1e-12)
    # no information at all (singular even after the trace-scaled regularisation), or a non-finite one
    assert newest_state_covariance(np.zeros((n, n)), K, inflation) is None
    info[0, 0] = np.nan
    assert newest_state_covariance(info, K, inflation) is None


def test_an_unknown_solver_is_a_config_error() -> None:
    from runtime.errors import ConfigError

    with pytest.raises(ConfigError, match="mle_solver must be one of lm, scipy-fd"):
        DynamicInitConfig(mle_solver="trf")
