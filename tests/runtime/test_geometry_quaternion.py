"""Quaternion conventions: Hamilton (w-first and xyzw) against scipy, JPL against OpenVINS's formula."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from runtime.geometry import (
    GeometryError,
    jpl_xyzw_to_rot,
    quat_wxyz_to_rot,
    quat_xyzw_to_rot,
    rot_to_jpl_xyzw,
    rot_to_quat_wxyz,
    rot_to_quat_xyzw,
)

RNG = np.random.default_rng(3)


def canonical(q_xyzw: np.ndarray) -> np.ndarray:
    return q_xyzw * np.where(q_xyzw[..., 3:] < 0, -1.0, 1.0)


def test_hamilton_xyzw_matches_scipy():
    rot = Rotation.random(300, random_state=1)
    q = rot.as_quat()  # scalar-last
    np.testing.assert_allclose(quat_xyzw_to_rot(q), rot.as_matrix(), atol=1e-14)
    np.testing.assert_allclose(rot_to_quat_xyzw(rot.as_matrix()), canonical(q), atol=1e-14)


def test_hamilton_wxyz_matches_scipy_scalar_first():
    rot = Rotation.random(300, random_state=2)
    q = rot.as_quat(scalar_first=True)
    np.testing.assert_allclose(quat_wxyz_to_rot(q), rot.as_matrix(), atol=1e-14)
    out = rot_to_quat_wxyz(rot.as_matrix())
    np.testing.assert_allclose(out, q * np.where(q[:, :1] < 0, -1.0, 1.0), atol=1e-14)
    assert np.all(out[:, 0] >= 0.0)


@pytest.mark.parametrize("angle", [0.0, 1e-9, np.pi / 2, np.pi - 1e-9, np.pi])
def test_matrix_to_quaternion_every_branch(angle):
    for axis in np.eye(3).tolist() + [[1.0, 1.0, 1.0], [-0.2, 0.4, 0.9]]:
        rv = np.asarray(axis) / np.linalg.norm(axis) * angle
        R = Rotation.from_rotvec(rv).as_matrix()
        np.testing.assert_allclose(quat_wxyz_to_rot(rot_to_quat_wxyz(R)), R, atol=1e-14)


def test_unnormalised_input_is_normalised_and_zero_rejected():
    q = np.array([2.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(quat_wxyz_to_rot(q), np.eye(3))
    with pytest.raises(GeometryError):
        quat_wxyz_to_rot(np.zeros(4))
    with pytest.raises(GeometryError):
        quat_xyzw_to_rot(np.zeros(3))


def jpl_formula(q_xyzw: np.ndarray) -> np.ndarray:
    """OpenVINS: R_GtoI = (2 w^2 - 1) I - 2 w [v]x + 2 v v^T."""
    v, w = q_xyzw[:3], q_xyzw[3]
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return (2 * w * w - 1) * np.eye(3) - 2 * w * vx + 2 * np.outer(v, v)


def test_jpl_matches_openvins_formula_and_round_trips():
    q = RNG.normal(size=(100, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    R = jpl_xyzw_to_rot(q)
    for k in range(100):
        np.testing.assert_allclose(R[k], jpl_formula(q[k]), atol=1e-14)
    np.testing.assert_allclose(rot_to_jpl_xyzw(R), canonical(q), atol=1e-13)


def test_jpl_q_GtoI_equals_hamilton_q_of_R_ItoG():
    R_ItoG = Rotation.random(50, random_state=4)
    q_ham = R_ItoG.as_quat()  # Hamilton x,y,z,w of R_ItoG (scipy)
    R_GtoI = R_ItoG.inv().as_matrix()
    q_jpl = rot_to_jpl_xyzw(R_GtoI)
    np.testing.assert_allclose(q_jpl, canonical(q_ham), atol=1e-14)
    # and a point expressed in G goes to I with the JPL matrix
    p_G = RNG.normal(size=3)
    np.testing.assert_allclose(jpl_xyzw_to_rot(q_jpl[0]) @ p_G, R_ItoG[0].inv().apply(p_G), atol=1e-14)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0, allow_nan=False), min_size=4, max_size=4).filter(
    lambda q: np.linalg.norm(q) > 1e-3))
def test_property_quaternion_round_trips_and_composition(q):
    q = np.asarray(q) / np.linalg.norm(q)
    R = quat_wxyz_to_rot(q)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-14)
    np.testing.assert_allclose(quat_wxyz_to_rot(rot_to_quat_wxyz(R)), R, atol=1e-14)
    np.testing.assert_allclose(np.abs(rot_to_quat_wxyz(R) @ q), 1.0, atol=1e-12)  # same up to sign
    # the Hamilton product composes like the matrices: R(q * q) = R(q) R(q)
    w, v = q[0], q[1:]
    qq = np.r_[w * w - v @ v, 2 * w * v + np.cross(v, v)]
    np.testing.assert_allclose(quat_wxyz_to_rot(qq), R @ R, atol=1e-13)
