"""Centre views kept for revisits (runtime/graph/views.py): archiving with thinning and a cap, compact
descriptors, and the view-overlap ranking against a closed-form expectation."""
from __future__ import annotations

import math

import numpy as np

from models.matcher.features import Features
from runtime.geometry import make_pose, so3_exp
from runtime.graph.config import RevisitConfig
from runtime.graph.revisits import RevisitView
from runtime.graph.views import ViewStore, view_overlap

W, H = 640, 480
K = np.array([[400.0, 0.0, 319.5], [0.0, 400.0, 239.5], [0.0, 0.0, 1.0]])


def grid_view(depth: float = 4.0, n: int = 20) -> RevisitView:
    """Keypoints on a regular grid over the whole image, all at one z-depth (a fronto-parallel wall)."""
    u, v = np.meshgrid(np.linspace(0, W - 1, n), np.linspace(0, H - 1, n))
    kp = np.column_stack([u.ravel(), v.ravel()])
    return RevisitView(K, kp, np.full(len(kp), depth), (W, H))


def features(rng: np.random.Generator, n: int = 50) -> Features:
    d = rng.standard_normal((n, 64)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    level = rng.integers(0, 3, n).astype(np.int8)           # pyramid features (RevisitConfig.view_scales)
    return Features(rng.uniform(0, 600, (n, 2)).astype(np.float32), np.ones(n, np.float32), d, (W, H), level)


def pose_at(x: float, yaw_deg: float = 0.0) -> np.ndarray:
    return make_pose(so3_exp(np.array([0.0, math.radians(yaw_deg), 0.0])), np.array([x, 0.0, 0.0]))


def test_overlap_is_one_for_the_same_camera_and_follows_a_sideways_shift():
    v = grid_view()
    assert view_overlap(v, np.eye(4), v, np.eye(4)) == 1.0
    # a moved sideways by half the wall width seen at 4 m: the half of b's wall beyond a's right border
    half = 0.5 * (W - 1) * 4.0 / K[0, 0]
    ov = view_overlap(v, pose_at(half), v, np.eye(4))
    assert abs(ov - 0.5) <= 1.0 / 20 + 1e-9           # one grid column of 20 either way


def test_overlap_is_zero_facing_away_and_ignores_invalid_depths():
    v = grid_view()
    assert view_overlap(v, pose_at(0.0, 180.0), v, np.eye(4)) == 0.0
    d = v.depth_at_kpts.copy()
    d[: len(d) // 2] = np.nan
    half_valid = RevisitView(K, v.kpts, d, (W, H))
    assert view_overlap(v, np.eye(4), half_valid, np.eye(4)) == 1.0
    none_valid = RevisitView(K, v.kpts, np.full(len(d), np.nan), (W, H))
    assert view_overlap(v, np.eye(4), none_valid, np.eye(4)) == 0.0


def test_overlap_counts_only_points_seen_along_close_rays_at_a_similar_range():
    v = grid_view()
    # a twice as far back on the same axis: every point of b is in a's image, at 1.25-1.5 x b's range
    back = pose_at(0.0) @ make_pose(np.eye(3), np.array([0.0, 0.0, -4.0]))
    assert view_overlap(v, back, v, np.eye(4)) == 1.0
    assert view_overlap(v, back, v, np.eye(4), max_scale_change=2.5) == 1.0
    assert view_overlap(v, back, v, np.eye(4), max_scale_change=1.2) == 0.0
    # a turned 40 deg about the wall centre (4 m ahead): the rays to the centre are 40 deg apart
    c = np.array([0.0, 0.0, 4.0])
    R = so3_exp(np.array([0.0, math.radians(40.0), 0.0]))
    side = make_pose(R, c - R @ c)
    seen = view_overlap(v, side, v, np.eye(4))
    assert seen > 0.3
    assert view_overlap(v, side, v, np.eye(4), max_ray_angle_deg=60.0) == seen
    # brute force: every wall point, its angle between the rays from both centres, and a's image
    expected = 0
    for (u, w_), d in zip(v.kpts, v.depth_at_kpts, strict=True):
        X = d * np.linalg.solve(K, [u, w_, 1.0])
        q = side[:3, :3].T @ (X - side[:3, 3])
        px = K @ q / q[2]
        ray_a = X - side[:3, 3]
        angle = math.degrees(math.acos(X @ ray_a / np.linalg.norm(X) / np.linalg.norm(ray_a)))
        expected += bool(q[2] > 0 and -0.5 <= px[0] <= W - 0.5 and -0.5 <= px[1] <= H - 0.5 and angle <= 30.0)
    ov30 = view_overlap(v, side, v, np.eye(4), max_ray_angle_deg=30.0)
    assert ov30 == expected / len(v.kpts) and 0.0 < ov30 < seen


def test_archive_keeps_the_older_view_of_a_place_and_compacts_descriptors():
    rng = np.random.default_rng(0)
    store = ViewStore(RevisitConfig(view_thin_radius_m=1.0, view_thin_angle_deg=30.0))
    f0 = features(rng)
    for j in range(4):
        store.add(j, f0 if j == 0 else features(rng), grid_view())
    assert store.archive(0, pose_at(0.0))
    assert not store.archive(1, pose_at(0.5, 20.0))   # same place, same direction: thinned
    assert store.archive(2, pose_at(0.5, 60.0))       # same place, another direction: kept
    assert store.archive(3, pose_at(2.0))             # another place: kept
    assert store.ids == [0, 2, 3] and 1 not in store
    assert (store.stats.archived, store.stats.thinned) == (3, 1)
    f, _ = store.get(0)
    assert f.desc.dtype == np.float32 and np.abs(f.desc - f0.desc).max() < 1e-3
    assert store._views[0].features.desc.dtype == np.float16
    assert np.array_equal(f.level, f0.level)                  # pyramid levels survive the archive


def test_archive_respects_the_cap_and_clear_forgets_everything():
    rng = np.random.default_rng(1)
    store = ViewStore(RevisitConfig(max_views=2))
    for j in range(3):
        store.add(j, features(rng), grid_view())
        store.archive(j, pose_at(5.0 * j))
    assert store.ids == [0, 1] and store.stats.capped == 1
    store.add(7, features(rng), grid_view())          # resident views are never capped
    assert 7 in store and len(store) == 3
    store.clear()
    assert len(store) == 0
