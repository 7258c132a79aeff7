"""Voxel fusion against a brute-force per-voxel average; removing a submap restores the grid."""
from __future__ import annotations

import numpy as np
import pytest

from runtime.mapping.fusion import VoxelGrid, key_centres, voxel_keys


def _brute_force(points, grey, weights, voxel):
    acc: dict = {}
    for p, g, w in zip(points, grey, weights, strict=True):
        k = tuple(int(np.floor(x / voxel)) for x in p)
        s = acc.setdefault(k, [np.zeros(3), 0.0, 0.0, 0])
        s[0] += w * p
        s[1] += w * g
        s[2] += w
        s[3] += 1
    return {k: (s[0] / s[2], s[1] / s[2], s[3]) for k, s in acc.items()}


def test_fusion_equals_brute_force_average():
    rng = np.random.default_rng(0)
    a = rng.uniform(-1, 1, (3000, 3))
    b = a[:1000] + rng.normal(0, 0.01, (1000, 3))       # overlapping second submap
    ga, gb = rng.integers(0, 256, 3000), rng.integers(0, 256, 1000)
    wa, wb = rng.uniform(0.5, 2, 3000), rng.uniform(0.5, 2, 1000)
    grid = VoxelGrid(0.1)
    grid.integrate(a, ga, wa)
    grid.integrate(b, gb, wb)
    pts, grey, n = grid.points()
    ref = _brute_force(np.r_[a, b], np.r_[ga, gb], np.r_[wa, wb], 0.1)
    assert len(pts) == len(ref)
    idx = np.floor(pts / 0.1).astype(int)  # each mean lies inside its voxel
    for k in range(len(pts)):
        mean, g, cnt = ref[tuple(idx[k])]
        assert np.allclose(pts[k], mean)
        assert abs(int(grey[k]) - g) <= 0.5 + 1e-9
        assert n[k] == cnt


def test_removing_a_submap_restores_the_previous_grid():
    rng = np.random.default_rng(1)
    a, b = rng.uniform(0, 2, (2000, 3)), rng.uniform(1, 3, (2000, 3))
    grid = VoxelGrid(0.04)
    grid.integrate(a)
    before = grid.points()
    grid.integrate(b)
    grid.integrate(b, sign=-1)
    after = grid.points()
    assert len(after[0]) == len(before[0])
    assert np.allclose(after[0], before[0]) and np.array_equal(after[2], before[2])
    with pytest.raises(ValueError, match="never integrated"):
        grid.integrate(rng.uniform(10, 11, (5, 3)), sign=-1)


def test_voxel_keys_round_trip_and_negative_coordinates():
    p = np.array([[-0.01, 0.0, 0.05], [1.0, -2.0, 3.0]])
    c = key_centres(voxel_keys(p, 0.04), 0.04)
    assert np.all(np.abs(c - p) <= 0.02 + 1e-12)
    assert np.allclose(c[0], [-0.02, 0.02, 0.06])
