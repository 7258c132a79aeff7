"""Triangulation checks as OpenVINS's FeatureInitializer: anchored in the newest observation, parallax
measured perpendicular to the ray (closed-form camera layouts)."""
from __future__ import annotations

import numpy as np

from runtime.msckf.triangulation import triangulate

# camera z along world +x, camera x along world -y, camera y along world -z
R_OC = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def _observe(p_O: np.ndarray, centres: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Noiseless normalised observations of p_O from cameras at `centres` (all with orientation R_OC)."""
    R = np.repeat(R_OC[None], len(centres), axis=0)
    pC = (p_O - centres) @ R_OC  # rows: R_OC^T (p_O - c)
    return R, centres.astype(float), pC[:, :2] / pC[:, 2:3]


NO_COND = 1e12  # conditioning check off, so that the baseline check alone decides


def test_motion_along_the_ray_is_rejected_and_sideways_motion_accepted() -> None:
    p_O = np.array([6.0, 0.0, 0.0])
    # 1 m of travel towards the point but only 5 cm sideways: distance / perpendicular baseline ~ 100 > 40
    # (the full offsets, 0.5 and 1 m, would give a ratio of 5)
    along = np.array([[0.0, 0.05, 0.0], [0.5, 0.0, 0.0], [1.0, 0.0, 0.0]])
    ok, _ = triangulate(*_observe(p_O, along), NO_COND, 0.1, 60.0, 40.0, 20)
    assert not ok
    # the same travel with 30 cm sideways: ratio 5 / 0.3 ~ 17 < 40, exact point
    side = np.array([[0.0, 0.3, 0.0], [0.5, 0.0, 0.0], [1.0, 0.0, 0.0]])
    ok, p = triangulate(*_observe(p_O, side), NO_COND, 0.1, 60.0, 40.0, 20)
    assert ok and np.allclose(p, p_O, atol=1e-8)
    # the threshold is the perpendicular offset: 5 / 0.15 = 33 passes, 5 / 0.1 = 50 does not
    for lateral, expect in ((0.15, True), (0.10, False)):
        cams = np.array([[0.0, lateral, 0.0], [1.0, 0.0, 0.0]])
        ok, _ = triangulate(*_observe(p_O, cams), NO_COND, 0.1, 60.0, 40.0, 20)
        assert ok is expect, lateral


def test_depth_limits_apply_in_the_newest_camera() -> None:
    p_O = np.array([7.0, 0.5, 0.2])
    cams = np.array([[0.0, 0.0, 0.0], [1.0, 0.4, 0.0], [2.0, 0.8, 0.1]])  # depths 7, 6, 5 m
    R, c, xn = _observe(p_O, cams)
    ok, p = triangulate(R, c, xn, 1e4, 0.1, 5.5, 40.0, 20)    # newest depth 5 m < 5.5 m
    assert ok and np.allclose(p, p_O, atol=1e-8)
    ok, _ = triangulate(R, c, xn, 1e4, 5.2, 60.0, 40.0, 20)   # newest depth 5 m < min 5.2 m
    assert not ok
    # reversed time order: the newest camera is now 7 m away
    ok, _ = triangulate(R[::-1].copy(), c[::-1].copy(), xn[::-1].copy(), 1e4, 0.1, 5.5, 40.0, 20)
    assert not ok
