"""Feed-forward initializer: exact recovery on noise-free windows, degenerate-motion rejection,
robustness to outlier points (paper Sec. IV-A/B)."""
from __future__ import annotations

import numpy as np
import pytest
from ffinit_synth import G0, make_window

from runtime.ffinit import FFInitConfig, Rejection, robust_solve, solve_linear
from runtime.ffinit.linear import build_system


def test_noise_free_window_recovers_scale_velocity_gravity_exactly():
    window, truth = make_window("general")
    sol = solve_linear(window)
    assert not isinstance(sol, Rejection), sol
    assert sol.scale == pytest.approx(truth.scale, rel=1e-9)
    np.testing.assert_allclose(sol.v0, truth.v0_I0, atol=1e-8)
    np.testing.assert_allclose(sol.g, truth.g_I0, atol=1e-8)
    assert np.linalg.norm(sol.g) == pytest.approx(G0)


def test_rows_vanish_at_the_true_state():
    window, truth = make_window("general", points=10)
    system = build_system(window)
    x = np.concatenate([[truth.scale], truth.v0_I0, truth.g_I0])
    assert np.max(system.residuals(x)) < 1e-10
    # and not at a wrong scale
    assert np.max(system.residuals(x * np.r_[1.1, np.ones(6)])) > 1e-4


def test_constant_velocity_window_is_rejected_as_ill_conditioned():
    window, _ = make_window("constant_velocity")
    res = solve_linear(window)
    assert isinstance(res, Rejection) and res.reason == "ill_conditioned", res
    res = robust_solve(window)
    assert isinstance(res, Rejection) and res.reason == "ill_conditioned", res


def test_pure_rotation_window_is_rejected_for_small_baseline():
    window, _ = make_window("pure_rotation")
    res = robust_solve(window)
    assert isinstance(res, Rejection) and res.reason == "small_baseline", res


def test_too_few_images_is_rejected():
    window, _ = make_window("general", n_images=3)
    res = robust_solve(window)
    assert isinstance(res, Rejection) and res.reason == "too_few_images"


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_scale_within_5_percent_with_30_percent_outlier_points(seed):
    # DA3 rotations nearly agree with the IMU (as after gyro-bias alignment); 30 % of the points have
    # grossly wrong depths (x/÷ 1.8..4) and all depths 5 % noise.
    window, truth = make_window("general", rot_noise_deg=0.02, depth_noise=0.05,
                                outlier_fraction=0.3, seed=seed)
    res = robust_solve(window, FFInitConfig(seed=seed))
    assert not isinstance(res, Rejection), res
    assert abs(res.solution.scale / truth.scale - 1) < 0.05
    # the robust search flags most injected outliers: the inlier set is far cleaner than 70/30
    assert res.inlier_fraction > 0.4


def test_robust_solution_noise_free_is_exact_and_accepted():
    window, truth = make_window("general")
    res = robust_solve(window)
    assert not isinstance(res, Rejection), res
    assert res.inlier_fraction == pytest.approx(1.0)
    assert res.solution.scale == pytest.approx(truth.scale, rel=1e-8)


def test_implausible_gravity_is_rejected():
    window, _ = make_window("general")
    window.dv = -window.dv  # mean specific force now points opposite to gravity
    res = robust_solve(window)
    assert isinstance(res, Rejection) and res.reason == "gravity_disagrees"
