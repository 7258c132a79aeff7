"""Placement (paper eq. placement) against a closed form: the scale acts on depth only."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from runtime.mapping.placement import backproject, place_points


def _pose(rotvec, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


def test_placement_matches_closed_form_and_scales_depth_only():
    K = np.array([[400.0, 0, 320], [0, 410.0, 240], [0, 0, 1]])
    T_MS = _pose([0.1, -0.2, 0.3], [1.0, 2.0, 0.5])
    T_SC = np.stack([_pose([0, 0, 0], [0, 0, 0]), _pose([0.0, 0.1, 0.0], [0.4, 0.0, 0.1])])
    u, v, d = np.array([320.0, 100.0]), np.array([240.0, 50.0]), np.array([2.0, 3.5])
    pts_C = backproject(d, K, u, v)
    # closed form: the principal-point pixel of depth d is (0, 0, d) in its camera
    assert np.allclose(pts_C[0], [0.0, 0.0, 2.0])
    assert np.allclose(pts_C[1], [(100 - 320) / 400 * 3.5, (50 - 240) / 410 * 3.5, 3.5])
    lam = np.log(1.2)
    p_M = place_points(pts_C, np.array([0, 1]), T_SC, T_MS, lam)
    for k, i in enumerate((0, 1)):
        T_MC = T_MS @ T_SC[i]
        ray = np.array([(u[k] - 320) / 400, (v[k] - 240) / 410, 1.0])
        expected = T_MC[:3, :3] @ (1.2 * d[k] * ray) + T_MC[:3, 3]
        assert np.allclose(p_M[k], expected)
    # depth-only: a point's distance from ITS camera centre scales by e^lambda; the camera centre
    # (the metric VIO translation of T_SC) does not move
    c1 = (T_MS @ T_SC[1])[:3, 3]
    p0 = place_points(pts_C[1:], np.array([1]), T_SC, T_MS, 0.0)[0]
    assert np.isclose(np.linalg.norm(p_M[1] - c1), 1.2 * np.linalg.norm(p0 - c1))
    # a similarity about S would instead move the non-centre camera: its point differs from ours
    sim = T_MS[:3, :3] @ (1.2 * (T_SC[1][:3, :3] @ pts_C[1] + T_SC[1][:3, 3])) + T_MS[:3, 3]
    assert np.linalg.norm(sim - p_M[1]) > 0.05
