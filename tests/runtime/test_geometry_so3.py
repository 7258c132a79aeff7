"""SO(3) maps and Jacobians against scipy's Rotation, matrix exponentials and finite differences."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

from runtime.geometry import (
    GeometryError,
    normalize_rotation,
    skew,
    so3_exp,
    so3_interpolate,
    so3_left_jacobian,
    so3_left_jacobian_inv,
    so3_log,
    so3_right_jacobian,
    so3_right_jacobian_inv,
    vee,
)

RNG = np.random.default_rng(7)


def random_rotvecs(n: int, max_angle: float = np.pi) -> np.ndarray:
    axis = RNG.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    return axis * RNG.uniform(0.0, max_angle, size=(n, 1))


def test_skew_is_cross_product_and_vee_inverts_it():
    a, b = RNG.normal(size=(10, 3)), RNG.normal(size=(10, 3))
    np.testing.assert_allclose(np.einsum("nij,nj->ni", skew(a), b), np.cross(a, b), atol=1e-14)
    np.testing.assert_allclose(vee(skew(a)), a, atol=0)
    np.testing.assert_allclose(skew(a[0]), -skew(a[0]).T)


def test_exp_matches_scipy_and_expm():
    phi = random_rotvecs(200)
    R = so3_exp(phi)
    np.testing.assert_allclose(R, Rotation.from_rotvec(phi).as_matrix(), atol=1e-14)
    np.testing.assert_allclose(so3_exp(phi[3]), expm(skew(phi[3])), atol=1e-13)
    assert so3_exp(phi.reshape(20, 10, 3)).shape == (20, 10, 3, 3)


def test_log_matches_scipy_over_the_whole_ball():
    phi = random_rotvecs(500, np.pi - 1e-6)
    R = Rotation.from_rotvec(phi).as_matrix()
    np.testing.assert_allclose(so3_log(R), phi, atol=1e-12)
    np.testing.assert_allclose(so3_log(R), Rotation.from_matrix(R).as_rotvec(), atol=1e-12)


@pytest.mark.parametrize("angle", [0.0, 1e-14, 1e-9, 1e-7, 1e-5, 1e-3, 0.1, 1.0, 2.0])
def test_log_exp_round_trip_small_and_moderate(angle):
    axis = np.array([0.3, -0.5, 0.8])
    phi = axis / np.linalg.norm(axis) * angle
    np.testing.assert_allclose(so3_log(so3_exp(phi)), phi, rtol=1e-12, atol=1e-18)


@pytest.mark.parametrize("eps", [0.0, 1e-15, 1e-12, 1e-9, 1e-6, 1e-3])
def test_log_near_pi(eps):
    axes = RNG.normal(size=(20, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    phi = axes * (np.pi - eps)
    R = Rotation.from_rotvec(phi).as_matrix()
    out = so3_log(R)
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), np.pi - eps, atol=1e-9)
    if eps == 0.0:  # the axis sign is arbitrary at pi; the rotation must be reproduced
        np.testing.assert_allclose(so3_exp(out), R, atol=1e-12)
    else:
        np.testing.assert_allclose(out, phi, atol=1e-7 if eps < 1e-8 else 1e-10)
    np.testing.assert_allclose(so3_exp(out), R, atol=1e-12)


def test_log_at_exact_pi_of_axis_rotations():
    for R in (np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0])):
        out = so3_log(R)
        assert np.isclose(np.linalg.norm(out), np.pi)
        np.testing.assert_allclose(so3_exp(out), R, atol=1e-15)


def numeric_right_jacobian(phi: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """d/d(dphi) of Log(Exp(phi)^T Exp(phi + dphi)) by central differences."""
    R = so3_exp(phi)
    J = np.zeros((3, 3))
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        J[:, k] = (so3_log(R.T @ so3_exp(phi + d)) - so3_log(R.T @ so3_exp(phi - d))) / (2 * h)
    return J


@pytest.mark.parametrize("angle", [0.0, 1e-6, 0.1, 0.24, 0.26, 1.0, 2.5, 3.0])
def test_right_and_left_jacobians_by_finite_differences(angle):
    axis = np.array([0.2, 0.9, -0.4])
    phi = axis / np.linalg.norm(axis) * angle
    np.testing.assert_allclose(so3_right_jacobian(phi), numeric_right_jacobian(phi), atol=2e-8)
    np.testing.assert_allclose(so3_left_jacobian(phi), numeric_right_jacobian(-phi), atol=2e-8)
    # Jl(phi) = R Jr(phi)
    np.testing.assert_allclose(so3_left_jacobian(phi), so3_exp(phi) @ so3_right_jacobian(phi), atol=1e-14)


def test_jacobian_inverses_are_inverses_across_the_series_switch():
    angles = np.array([0.0, 1e-9, 1e-4, 0.2, 0.2499, 0.25, 0.2501, 0.5, 1.5, 3.0, 3.14159, 4.0, 6.0])
    axis = np.array([0.6, -0.1, 0.79])
    phi = axis[None, :] / np.linalg.norm(axis) * angles[:, None]
    eye = np.broadcast_to(np.eye(3), (len(angles), 3, 3))
    np.testing.assert_allclose(so3_right_jacobian(phi) @ so3_right_jacobian_inv(phi), eye, atol=1e-12)
    np.testing.assert_allclose(so3_left_jacobian(phi) @ so3_left_jacobian_inv(phi), eye, atol=1e-12)
    inv = np.linalg.inv(so3_right_jacobian(phi))
    np.testing.assert_allclose(inv, so3_right_jacobian_inv(phi), atol=1e-11)


def test_right_jacobian_inverse_is_singular_at_two_pi():
    with pytest.raises(GeometryError):
        so3_right_jacobian_inv(np.array([0.0, 0.0, 2 * np.pi]))


def test_first_order_exp_identity():
    phi = np.array([0.4, -1.1, 0.7])
    dphi = np.array([1e-5, -2e-5, 0.5e-5])
    lhs = so3_exp(phi + dphi)
    np.testing.assert_allclose(lhs, so3_exp(phi) @ so3_exp(so3_right_jacobian(phi) @ dphi), atol=1e-9)
    np.testing.assert_allclose(lhs, so3_exp(so3_left_jacobian(phi) @ dphi) @ so3_exp(phi), atol=1e-9)


def test_bad_shapes_raise_geometry_error():
    with pytest.raises(GeometryError, match=r"\(\.\.\., 3\)"):
        so3_exp(np.zeros(4))
    with pytest.raises(GeometryError):
        so3_log(np.zeros((3, 4)))
    with pytest.raises(ValueError):  # GeometryError is also a ValueError
        skew([1.0, 2.0])
    with pytest.raises(GeometryError, match="non-finite"):
        so3_exp([0.0, np.nan, 1.0])
    with pytest.raises(GeometryError, match="non-finite"):
        so3_log(np.full((3, 3), np.inf))


def test_normalize_rotation_is_scipy_nearest_rotation():
    R = Rotation.from_rotvec(random_rotvecs(50)).as_matrix()
    noisy = R + 1e-3 * RNG.normal(size=R.shape)
    out = normalize_rotation(noisy)
    eye = np.broadcast_to(np.eye(3), out.shape)
    np.testing.assert_allclose(out @ np.swapaxes(out, 1, 2), eye, atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(out), 1.0, atol=1e-14)
    # the polar factor minimises the Frobenius distance: compare with scipy's orthogonal projection
    from scipy.linalg import polar

    for k in range(5):
        np.testing.assert_allclose(out[k], polar(noisy[k])[0], atol=1e-12)
    # a reflection is projected to a proper rotation
    assert np.isclose(np.linalg.det(normalize_rotation(np.diag([1.0, 1.0, -1.0]))), 1.0)


def test_interpolation_is_scipy_slerp():
    from scipy.spatial.transform import Slerp

    key = Rotation.from_rotvec(random_rotvecs(2, 3.0))
    alphas = np.linspace(0.0, 1.0, 11)
    expected = Slerp([0.0, 1.0], key)(alphas).as_matrix()
    R0 = key[0].as_matrix()
    R1 = key[1].as_matrix()
    np.testing.assert_allclose(so3_interpolate(R0, R1, alphas), expected, atol=1e-12)
    np.testing.assert_allclose(so3_interpolate(R0, R1, 0.0), R0, atol=1e-14)
    np.testing.assert_allclose(so3_interpolate(R0, R1, 1.0), R1, atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-10.0, 10.0, allow_nan=False), min_size=3, max_size=3))
def test_property_exp_is_orthonormal_and_log_recovers_rotation(v):
    phi = np.array(v)
    R = so3_exp(phi)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-13)
    assert np.isclose(np.linalg.det(R), 1.0)
    out = so3_log(R)
    assert np.linalg.norm(out) <= np.pi + 1e-12
    np.testing.assert_allclose(so3_exp(out), R, atol=1e-12)


def test_rot_z_is_the_exponential_about_z_batched_and_keeps_gravity_exact():
    from runtime.geometry import rot_z

    yaws = np.array([[-3.0, 0.0], [0.4, 2.5]])
    R = rot_z(yaws)
    assert R.shape == (2, 2, 3, 3)
    for yaw, Ry in zip(yaws.ravel(), R.reshape(-1, 3, 3), strict=True):
        np.testing.assert_allclose(Ry, so3_exp(np.array([0.0, 0.0, yaw])), atol=1e-12)
        assert np.array_equal(Ry[2], [0.0, 0.0, 1.0]) and np.array_equal(Ry[:, 2], [0.0, 0.0, 1.0])


def test_kabsch_is_scipy_align_vectors_one_set_or_a_stack():
    from runtime.geometry.so3 import kabsch_rotation

    R_true = Rotation.from_rotvec(random_rotvecs(4)).as_matrix()
    a = RNG.normal(size=(4, 12, 3))
    b = np.einsum("kij,knj->kni", R_true, a) + RNG.normal(0.0, 0.01, (4, 12, 3))
    stacked = kabsch_rotation(a, b)
    assert stacked.shape == (4, 3, 3)
    for k in range(4):
        # scipy: the rotation taking a's vectors to b's in the least-squares sense
        expected = Rotation.align_vectors(b[k], a[k])[0].as_matrix()
        np.testing.assert_allclose(kabsch_rotation(a[k], b[k]), expected, atol=1e-9)
        np.testing.assert_allclose(stacked[k], expected, atol=1e-9)
    # two pairs only (the RANSAC's samples) and a reflected best fit: still a proper rotation
    two = kabsch_rotation(a[:, :2], b[:, :2])
    np.testing.assert_allclose(np.linalg.det(two), 1.0, atol=1e-12)
    mirrored = kabsch_rotation(a[0], a[0] * np.array([1.0, 1.0, -1.0]))
    assert np.linalg.det(mirrored) == pytest.approx(1.0)
