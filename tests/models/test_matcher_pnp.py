"""PnP-RANSAC verification gates on synthetic correspondences with known pose."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from models.matcher import Matcher, PnPGates, verify_pnp
from runtime.errors import DataError
from runtime.geometry import make_pose, so3_exp

K = np.array([[450.0, 0, 320], [0, 450.0, 240], [0, 0, 1]])


def scene(n_in: int, n_out: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    T_CW = make_pose(so3_exp(np.array([0.1, -0.2, 0.05])), np.array([0.3, -0.1, 0.5]))
    p_C = np.column_stack([rng.uniform(-2, 2, n_in), rng.uniform(-1.5, 1.5, n_in), rng.uniform(2, 6, n_in)])
    p_W = (p_C - T_CW[:3, 3]) @ T_CW[:3, :3]
    uv = p_C[:, :2] / p_C[:, 2:] * [K[0, 0], K[1, 1]] + K[:2, 2] + rng.normal(0, 0.3, (n_in, 2))
    out_W = rng.uniform(-3, 3, (n_out, 3)) + [0, 0, 4]
    out_uv = rng.uniform([0, 0], [640, 480], (n_out, 2))
    return np.vstack([p_W, out_W]), np.vstack([uv, out_uv]), T_CW


def test_accepts_and_recovers_pose_with_outliers():
    cv2.setRNGSeed(0)
    P, uv, T_CW = scene(120, 60)
    r = verify_pnp(P, uv, K)
    assert r.accepted and r.reason == "accepted"
    assert r.n_matches == 180 and 110 <= r.n_inliers <= 125
    assert set(r.inliers.tolist()) <= set(range(120)) | set(range(120, 180))
    assert np.mean(r.inliers < 120) > 0.95
    np.testing.assert_allclose(r.T_CW, T_CW, atol=0.02)
    assert r.rmse_px < 1.0


def test_rejects_too_few_matches():
    P, uv, _ = scene(40, 5)
    r = verify_pnp(P, uv, K)
    assert not r.accepted and "too few matches" in r.reason and r.n_matches == 45


def test_rejects_low_inlier_support():
    cv2.setRNGSeed(1)
    P, uv, _ = scene(25, 100, seed=2)
    r = verify_pnp(P, uv, K)
    assert not r.accepted and ("inlier" in r.reason or "no pose" in r.reason)
    cv2.setRNGSeed(1)
    P, uv, _ = scene(45, 155, seed=3)  # enough inliers for the count gate, fraction 0.225 < 0.25
    r = verify_pnp(P, uv, K, PnPGates(iterations=3000))
    assert not r.accepted and (
        "fraction" in r.reason or "too few inliers" in r.reason or "no pose" in r.reason
    )
    if "fraction" in r.reason:
        assert r.inlier_fraction < 0.25 and r.n_inliers >= 30


def test_bad_input_and_non_finite_rows():
    with pytest.raises(DataError):
        verify_pnp(np.zeros((10, 2)), np.zeros((10, 2)), K)
    P, uv, _ = scene(80, 0)
    P[:5] = np.nan
    r = verify_pnp(P, uv, K)
    assert r.n_matches == 75 and r.accepted


def test_orb_matcher_end_to_end_with_pnp():
    """Render a textured plane in two views; ORB matches + known depth must pass the gates."""
    rng = np.random.default_rng(4)
    tex = cv2.GaussianBlur(rng.integers(0, 255, (480, 640)).astype(np.uint8), (0, 0), 1.5)
    tex = cv2.equalizeHist(tex)
    # plane z = 4 m seen by camera a (identity) and camera b (x_b = R x_a + t): H = K (R + t n^T / d) K^-1
    R = so3_exp(np.array([0.0, 0.05, 0.02]))
    t = np.array([0.2, 0.0, 0.05])
    n, d = np.array([0, 0, 1.0]), 4.0
    H = K @ (R + np.outer(t, n) / d) @ np.linalg.inv(K)
    img_b = cv2.warpPerspective(tex, H, (640, 480))
    m = Matcher(None, top_k=1500).match(tex, img_b)
    pa = m.points_a.astype(np.float64)
    P = np.column_stack([(pa - K[:2, 2]) / [K[0, 0], K[1, 1]], np.ones(len(pa))]) * d
    r = verify_pnp(P, m.points_b, K)
    assert r.accepted, r.reason
    np.testing.assert_allclose(r.T_CW[:3, :3], R, atol=0.01)
    np.testing.assert_allclose(r.T_CW[:3, 3], t, atol=0.03)
