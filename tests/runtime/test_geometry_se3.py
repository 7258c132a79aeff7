"""SE(3) exp/log/inverse against scipy's matrix exponential and logarithm."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.linalg import expm, logm

from runtime.geometry import GeometryError, make_pose, se3_exp, se3_inverse, se3_log, so3_exp

RNG = np.random.default_rng(11)


def twist_matrix(xi: np.ndarray) -> np.ndarray:
    rho, phi = xi[:3], xi[3:]
    M = np.zeros((4, 4))
    M[:3, :3] = np.array([[0, -phi[2], phi[1]], [phi[2], 0, -phi[0]], [-phi[1], phi[0], 0]])
    M[:3, 3] = rho
    return M


@pytest.mark.parametrize("scale", [0.0, 1e-8, 1e-3, 0.5, 2.0])
def test_se3_exp_matches_expm(scale):
    for _ in range(10):
        xi = RNG.normal(size=6)
        xi[3:] *= scale
        np.testing.assert_allclose(se3_exp(xi), expm(twist_matrix(xi)), atol=1e-12)


def test_se3_log_matches_logm_and_round_trips():
    xi = RNG.normal(size=(50, 6))
    norms = np.linalg.norm(xi[:, 3:], axis=1, keepdims=True)
    xi[:, 3:] *= RNG.uniform(0.0, 3.1, size=(50, 1)) / norms  # inside the principal ball |phi| < pi
    T = se3_exp(xi)
    np.testing.assert_allclose(se3_log(T), xi, atol=1e-12)
    M = np.real(logm(T[0]))
    np.testing.assert_allclose(se3_log(T[0]), np.r_[M[:3, 3], M[2, 1], M[0, 2], M[1, 0]], atol=1e-10)


def test_se3_log_near_pi():
    xi = np.array([0.3, -1.0, 2.0, 0.0, 0.0, np.pi - 1e-9])
    np.testing.assert_allclose(se3_exp(se3_log(se3_exp(xi))), se3_exp(xi), atol=1e-9)


def test_inverse_and_make_pose():
    R = so3_exp(RNG.normal(size=(8, 3)))
    p = RNG.normal(size=(8, 3))
    T = make_pose(R, p)
    np.testing.assert_allclose(T @ se3_inverse(T), np.broadcast_to(np.eye(4), (8, 4, 4)), atol=1e-14)
    np.testing.assert_allclose(se3_inverse(T), np.linalg.inv(T), atol=1e-13)
    x_B = RNG.normal(size=3)
    np.testing.assert_allclose(T[0, :3, :3] @ x_B + T[0, :3, 3], R[0] @ x_B + p[0])
    assert make_pose(np.eye(3), p).shape == (8, 4, 4)
    with pytest.raises(GeometryError):
        se3_exp(np.zeros(3))


@settings(max_examples=150, deadline=None)
@given(st.lists(st.floats(-5.0, 5.0, allow_nan=False), min_size=6, max_size=6))
def test_property_se3_log_exp_round_trip(v):
    xi = np.asarray(v)
    T = se3_exp(xi)
    np.testing.assert_allclose(se3_exp(se3_log(T)), T, atol=1e-10)
    np.testing.assert_allclose(T @ se3_inverse(T), np.eye(4), atol=1e-12)
    if np.linalg.norm(xi[3:]) < np.pi - 1e-6:
        np.testing.assert_allclose(se3_log(T), xi, atol=1e-9)
