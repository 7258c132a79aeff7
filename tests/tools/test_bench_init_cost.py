"""`davio bench init-cost`: the errors against the truth it reports, on states whose errors are known."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from runtime.geometry import so3_exp
from runtime.msckf.init_common import InitResult
from tools.benchmarks.init_cost import _errors, _not_converged, _reached_refinement, _stats, tilt_sigma_deg


def test_errors_are_the_gravity_tilt_and_the_body_frame_velocity_difference():
    R_WI = so3_exp(np.array([0.2, -0.1, 1.3]))
    v_W = np.array([0.5, -0.3, 0.1])
    truth = SimpleNamespace(sample=lambda t: SimpleNamespace(R=R_WI[None], v=v_W[None]))
    # yaw is a gauge of O: a state yawed by 40 deg with the same body-frame velocity has no error
    yaw = so3_exp(np.array([0.0, 0.0, np.radians(40.0)]))
    cov = np.eye(15) * np.radians(0.5) ** 2       # 0.5 deg about every axis
    same = InitResult(0, yaw @ R_WI, np.zeros(3), yaw @ v_W, np.zeros(3), np.zeros(3), cov, "dynamic")
    assert _errors(same, truth) == pytest.approx({"velocity_m_s": 0.0, "gravity_deg": 0.0,
                                                  "gravity_sigmas": 0.0}, abs=1e-6)
    # tilted by 3 deg about a horizontal body axis, and 0.2 m/s off along body z
    up_I = R_WI[2, :]
    axis = np.cross(up_I, [1.0, 0.0, 0.0])
    tilted = R_WI @ so3_exp(np.radians(3.0) * axis / np.linalg.norm(axis))
    v_wrong = tilted @ (R_WI.T @ v_W + np.array([0.0, 0.0, 0.2]))
    off = InitResult(0, tilted, np.zeros(3), v_wrong, np.zeros(3), np.zeros(3), cov, "dynamic")
    assert _errors(off, truth) == pytest.approx({"velocity_m_s": 0.2, "gravity_deg": 3.0,
                                                 "gravity_sigmas": 6.0}, rel=1e-6)


def test_the_tilt_sigma_ignores_the_rotation_about_gravity_and_takes_the_worst_tilt():
    """Against sampling: rotations drawn from the covariance, and the spread of the gravity they give."""
    rng = np.random.default_rng(1)
    R_OI = so3_exp(np.array([0.4, -0.3, 0.9]))
    g_I = R_OI.T @ np.array([0.0, 0.0, -1.0])
    # 10 deg about gravity (yaw: moves nothing), 0.3 and 0.8 deg about two tilt axes
    a = np.cross(g_I, [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(g_I, a)
    axes = np.column_stack([g_I, a, b])
    cov = np.eye(15)
    cov[:3, :3] = axes @ np.diag(np.radians([10.0, 0.3, 0.8]) ** 2) @ axes.T
    res = InitResult(0, R_OI, np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), cov, "dynamic")
    assert tilt_sigma_deg(res) == pytest.approx(0.8, rel=1e-9)
    theta = rng.multivariate_normal(np.zeros(3), cov[:3, :3], 20000)
    g = np.einsum("nji,j->ni", R_OI @ so3_exp(theta), np.array([0.0, 0.0, -1.0]))    # (R_OI Exp)^T g_O
    tilt_b = np.degrees(np.arcsin(np.clip(g @ a, -1, 1)))    # the tilt's component that theta along b makes
    assert np.std(tilt_b) == pytest.approx(0.8, rel=0.03)


def test_stats_of_no_attempt_and_of_some():
    assert _stats([]) == {"n": 0, "median_ms": None, "p90_ms": None, "max_ms": None}
    s = _stats([1.0, 2.0, 3.0, 10.0])
    assert s["n"] == 4 and s["median_ms"] == 2.5 and s["max_ms"] == 10.0
    assert s["p90_ms"] == pytest.approx(np.percentile([1, 2, 3, 10], 90))


def test_a_state_without_covariance_has_no_error_in_sigmas_and_refusals_are_told_apart():
    R_WI = so3_exp(np.array([0.2, -0.1, 1.3]))
    truth = SimpleNamespace(sample=lambda t: SimpleNamespace(R=R_WI[None], v=np.zeros((1, 3))))
    bare = InitResult(0, R_WI, np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), None, "dynamic")
    assert _errors(bare, truth)["gravity_sigmas"] is None

    def init(code):
        return SimpleNamespace(log=SimpleNamespace(last=None if code is None else SimpleNamespace(code=code)))

    refused = init("mle_not_converged")
    assert _not_converged(refused, None) and _reached_refinement(refused, None)
    assert not _not_converged(init("mle_failed"), None) and _reached_refinement(init("mle_failed"), None)
    assert not _not_converged(init("insufficient_parallax"), None)
    assert not _reached_refinement(init("insufficient_parallax"), None)
    assert not _not_converged(init("mle_not_converged"), bare)   # an accepted attempt is not a refusal
