"""The numba kernels agree with the numpy implementations (and are callable from other numba code)."""
from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from runtime.geometry import (
    normalize_rotation,
    skew,
    so3_exp,
    so3_left_jacobian,
    so3_left_jacobian_inv,
    so3_log,
    so3_right_jacobian,
    so3_right_jacobian_inv,
)
from runtime.geometry.kernels import (
    nb_left_jacobian,
    nb_left_jacobian_inv,
    nb_normalize_rotation,
    nb_right_jacobian,
    nb_right_jacobian_inv,
    nb_skew,
    nb_so3_exp,
    nb_so3_log,
)

ANGLES = [0.0, 1e-12, 1e-7, 1e-3, 0.2, 0.25, 0.3, 1.0, 2.0, 3.0, np.pi - 1e-8, np.pi]


@pytest.mark.parametrize("angle", ANGLES)
def test_kernels_match_numpy(angle):
    rng = np.random.default_rng(int(angle * 1000))
    for _ in range(5):
        axis = rng.normal(size=3)
        phi = axis / np.linalg.norm(axis) * angle
        np.testing.assert_allclose(nb_skew(phi), skew(phi), atol=0)
        R = nb_so3_exp(phi)
        np.testing.assert_allclose(R, so3_exp(phi), atol=1e-15)
        log = nb_so3_log(R)
        np.testing.assert_allclose(log, so3_log(R), atol=1e-12)
        np.testing.assert_allclose(nb_so3_exp(log), R, atol=1e-12)
        np.testing.assert_allclose(nb_right_jacobian(phi), so3_right_jacobian(phi), atol=1e-15)
        np.testing.assert_allclose(nb_left_jacobian(phi), so3_left_jacobian(phi), atol=1e-15)
        np.testing.assert_allclose(nb_right_jacobian_inv(phi), so3_right_jacobian_inv(phi), atol=1e-14)
        np.testing.assert_allclose(nb_left_jacobian_inv(phi), so3_left_jacobian_inv(phi), atol=1e-14)
        M = R + 1e-4 * rng.normal(size=(3, 3))
        np.testing.assert_allclose(nb_normalize_rotation(M), normalize_rotation(M), atol=1e-13)


@njit(cache=True)
def _compose_in_numba(phis):
    R = np.eye(3)
    for k in range(phis.shape[0]):
        R = R @ nb_so3_exp(phis[k])
    return nb_so3_log(R)


def test_kernels_compose_inside_numba():
    phis = np.full((4, 3), 0.0)
    phis[:, 2] = 0.5
    np.testing.assert_allclose(_compose_in_numba(phis), [0.0, 0.0, 2.0], atol=1e-14)


@pytest.mark.parametrize("angle", ANGLES)
def test_allocation_free_kernels_match_numpy(angle):
    from runtime.geometry.kernels import nb_matmul3_into, nb_right_jacobian_into, nb_so3_exp_into

    rng = np.random.default_rng(int(angle * 1000) + 1)
    axis = rng.normal(size=3)
    phi = axis / np.linalg.norm(axis) * angle
    out = np.full((3, 3), np.nan)
    nb_so3_exp_into(phi[0], phi[1], phi[2], out)
    np.testing.assert_allclose(out, so3_exp(phi), atol=1e-15)
    nb_right_jacobian_into(phi[0], phi[1], phi[2], out)
    np.testing.assert_allclose(out, so3_right_jacobian(phi), atol=1e-15)
    A, B = rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
    nb_matmul3_into(A, B, out)
    np.testing.assert_allclose(out, A @ B, atol=1e-14)
    nb_matmul3_into(A, B, out, True)
    np.testing.assert_allclose(out, A.T @ B, atol=1e-14)
