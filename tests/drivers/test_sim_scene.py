"""Scenes: reproducible, enclosing the trajectory with clearance, textured; surface samples on surfaces."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.sim.bvh import build_bvh
from drivers.sim.scene import build_scene
from drivers.sim.texture import LOW_TEXTURE, REFLECTIVE, TEXTURED, strength_of
from runtime.errors import ConfigError


@pytest.fixture(scope="module")
def path() -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, 400)
    return np.stack([2.0 * np.cos(t), 1.5 * np.sin(t), 1.2 + 0.3 * np.sin(2 * t)], axis=1)


@pytest.fixture(scope="module")
def scene(path: np.ndarray):
    return build_scene(path, seed=2)


def test_scene_is_seeded_and_reproducible(path: np.ndarray) -> None:
    a = build_scene(path, seed=3)
    b = build_scene(path, seed=3)
    c = build_scene(path, seed=4)
    np.testing.assert_array_equal(a.box_min, b.box_min)
    np.testing.assert_array_equal(a.atlas.albedo, b.atlas.albedo)
    assert a.box_min.shape != c.box_min.shape or np.abs(a.box_min - c.box_min).max() > 0.01


@pytest.mark.parametrize("style", ["room", "hall"])
def test_scene_encloses_the_trajectory_with_clearance(path: np.ndarray, style: str) -> None:
    s = build_scene(path, seed=1, style=style, clearance_m=0.6)
    assert np.all(path > s.box_min[0]) and np.all(path < s.box_max[0])
    for lo, hi in zip(s.box_min[1:], s.box_max[1:], strict=True):
        d = np.linalg.norm(np.maximum(np.maximum(lo - path, path - hi), 0.0), axis=1)
        assert d.min() > 0.6
    kinds = set(s.kinds)
    assert {"room", "box", "panel"} <= kinds
    assert s.n_boxes > 10
    mats = set(s.face_material.tolist())
    assert {TEXTURED, LOW_TEXTURE} <= mats
    if style == "hall":
        assert (s.box_max[0] - s.box_min[0])[2] >= 6.0


def test_scene_contains_reflective_surfaces(scene) -> None:
    assert REFLECTIVE in scene.face_material


def test_bad_style_or_positions_are_config_errors(path: np.ndarray) -> None:
    with pytest.raises(ConfigError):
        build_scene(path, style="cave")
    with pytest.raises(ConfigError):
        build_scene(np.full((3, 3), np.nan))


def test_surface_points_lie_on_surfaces_and_not_inside_objects(scene) -> None:
    s = scene
    pts, grey = s.surface_points(0.1)
    assert pts.shape[0] == grey.shape[0] > 1000
    assert s.surface_distance(pts).max() < 1e-9
    assert not s.inside_any_object(pts, margin=1e-3).any()
    assert 0.0 <= grey.min() and grey.max() <= 1.0


def test_surface_distance_of_known_points(scene) -> None:
    s = scene
    lo, hi = s.box_min[0], s.box_max[0]
    centre = 0.5 * (lo + hi)
    p = np.array([[centre[0], centre[1], lo[2] + 0.25]])  # 25 cm above the floor, unless an object is nearer
    assert s.surface_distance(p)[0] <= 0.25 + 1e-12


def test_texture_strength_separates_textured_from_plain() -> None:
    rng = np.random.default_rng(0)
    plain = np.full((64, 64), 0.6, np.float32)
    noisy = (0.5 + 0.2 * rng.standard_normal((64, 64))).astype(np.float32)
    assert strength_of(plain).max() == 0.0
    assert strength_of(noisy).mean() > 0.5


def test_bvh_covers_every_group_once() -> None:
    rng = np.random.default_rng(1)
    lo = rng.uniform(-5, 5, (37, 3))
    hi = lo + rng.uniform(0.1, 1.0, (37, 3))
    bvh = build_bvh(lo, hi)
    assert sorted(bvh.order.tolist()) == list(range(37))
    leaves = bvh.left < 0
    for node in np.nonzero(leaves)[0]:
        groups = bvh.order[bvh.first[node] : bvh.first[node] + bvh.count[node]]
        assert np.all(lo[groups] >= bvh.node_min[node] - 1e-12) and np.all(
            hi[groups] <= bvh.node_max[node] + 1e-12
        )
    inner = ~leaves
    for node in np.nonzero(inner)[0]:
        for child in (bvh.left[node], bvh.right[node]):
            assert np.all(bvh.node_min[child] >= bvh.node_min[node]) and np.all(
                bvh.node_max[child] <= bvh.node_max[node]
            )
