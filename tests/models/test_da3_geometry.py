"""Umeyama similarity fit and DA3 pose normalisation / resize intrinsics."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from models.da3.contract import da3_resolution
from models.da3.preprocess import normalise_poses, resize_matrix
from models.da3.similarity import umeyama_sim3
from runtime.geometry import make_pose, so3_exp


def test_umeyama_recovers_exact_similarity():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(6, 3))
    R = so3_exp(np.array([0.3, -0.5, 1.1]))
    y = 2.7 * x @ R.T + np.array([1.0, -2.0, 0.5])
    sim = umeyama_sim3(x, y)
    assert sim.s == pytest.approx(2.7) and sim.rmse_y < 1e-12
    np.testing.assert_allclose(sim.R, R, atol=1e-12)
    np.testing.assert_allclose(sim.t, [1.0, -2.0, 0.5], atol=1e-12)


def test_umeyama_rmse_and_degenerate_input():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(50, 3))
    noise = rng.normal(scale=0.01, size=(50, 3))
    sim = umeyama_sim3(x, 0.5 * x + noise)
    assert sim.s == pytest.approx(0.5, abs=0.01)
    assert sim.rmse_y == pytest.approx(np.sqrt((noise**2).sum(1).mean()), rel=0.2)
    with pytest.raises(ValueError, match="coincide"):
        umeyama_sim3(np.ones((4, 3)), rng.normal(size=(4, 3)))
    with pytest.raises(ValueError):
        umeyama_sim3(x[:1], x[:1])


def test_normalise_poses_keeps_relative_motion():
    rng = np.random.default_rng(2)
    T_WC = np.stack(
        [make_pose(so3_exp(rng.normal(scale=0.3, size=3)), rng.normal(size=3) * 3) for _ in range(5)]
    )
    T_CW = np.linalg.inv(T_WC)
    E, d = normalise_poses(T_CW)
    np.testing.assert_allclose(E[0], np.eye(4), atol=1e-12)
    dists = np.sort(np.linalg.norm(T_WC[:, :3, 3] - T_WC[0, :3, 3], axis=1))
    assert d == pytest.approx(dists[2])
    # relative pose between views 1 and 3 is preserved up to the translation scale
    rel_in = T_CW[3] @ T_WC[1]
    rel_out = E[3] @ np.linalg.inv(E[1])
    np.testing.assert_allclose(rel_out[:3, :3], rel_in[:3, :3], atol=1e-9)
    np.testing.assert_allclose(rel_out[:3, 3] * d, rel_in[:3, 3], atol=1e-9)
    # tiny motion: the scale is clamped at 0.1 m
    _, d_small = normalise_poses(np.stack([np.eye(4), make_pose(np.eye(3), [0.01, 0, 0])] * 2))
    assert d_small == 0.1


def test_resize_matrix_matches_opencv_pixel_mapping():
    # a single bright pixel blob moved by cv2.resize lands where the matrix says
    img = np.zeros((60, 90), np.float32)
    cv2.circle(img, (30, 20), 6, 1.0, -1)
    out = cv2.resize(img, (42, 28), interpolation=cv2.INTER_LINEAR)
    v, u = np.indices(out.shape)
    centroid = np.array([(u * out).sum(), (v * out).sum()]) / out.sum()
    A = resize_matrix((60, 90), (28, 42))
    np.testing.assert_allclose(A[:2, :2] @ [30, 20] + A[:2, 2], centroid, atol=0.05)


def test_da3_resolution_rule():
    assert da3_resolution(640, 480) == (378, 504)
    assert da3_resolution(752, 480) == (322, 504)
    with pytest.raises(ValueError):
        da3_resolution(0, 10)
