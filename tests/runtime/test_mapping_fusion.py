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


@pytest.mark.parametrize("pending_rows", [None, 0, 1, 700])
def test_pending_sums_join_the_grid_as_brute_force_whenever_they_do(pending_rows):
    """However long added points wait as per-voxel sums before they join the sorted grid (every call, or
    after hundreds of rows, or at the first read), the grid is the brute-force average, removals included."""
    rng = np.random.default_rng(2)
    chunks = [rng.uniform(-1, 1, (400, 3)) + [0.3 * k, 0, 0] for k in range(12)]
    greys = [rng.integers(0, 256, 400) for _ in chunks]
    grid = VoxelGrid(0.1, pending_rows=pending_rows)
    for k, (c, g) in enumerate(zip(chunks, greys, strict=True)):
        grid.integrate(c, g)
        if k == 6:
            grid.integrate(chunks[3], greys[3], sign=-1)      # a submap moved: taken out mid-stream
            assert len(grid) == len(_brute_force(np.concatenate(chunks[:3] + chunks[4:7]),
                                                 np.concatenate(greys[:3] + greys[4:7]), np.ones(2400), 0.1))
    kept = [k for k in range(12) if k != 3]
    ref = _brute_force(np.concatenate([chunks[k] for k in kept]), np.concatenate([greys[k] for k in kept]),
                       np.ones(400 * len(kept)), 0.1)
    pts, grey, n = grid.points()
    assert len(pts) == len(ref) and np.all(np.diff(grid.keys) > 0)
    for p, g, cnt in zip(pts, grey, n, strict=True):
        mean, g_ref, cnt_ref = ref[tuple(int(np.floor(x / 0.1)) for x in p)]
        assert np.allclose(p, mean) and abs(int(g) - g_ref) <= 0.5 + 1e-9 and cnt == cnt_ref


def test_pending_sums_are_bounded_by_the_grid_size():
    """Without a set limit, pending rows join once they are as many as the grid's voxels (at least
    MERGE_MIN_ROWS): what waits never holds more than the grid, so memory stays within twice it."""
    rng = np.random.default_rng(3)
    grid = VoxelGrid(0.01)
    grid.MERGE_MIN_ROWS = 5000
    cells = set()
    for k in range(40):
        pts = rng.uniform(0, 1, (1000, 3)) + [k, 0, 0]
        cells |= {tuple(c) for c in np.floor(pts / 0.01).astype(int)}
        grid.integrate(pts)
        assert grid._pending_rows < max(grid._keys.size, 5000) + 1000
    assert grid._pending and grid.nbytes() > sum(a.nbytes for a in (grid._keys, grid._w, grid._wp, grid._n))
    assert len(grid) == len(cells) and not grid._pending


def test_voxel_keys_round_trip_and_negative_coordinates():
    p = np.array([[-0.01, 0.0, 0.05], [1.0, -2.0, 3.0]])
    c = key_centres(voxel_keys(p, 0.04), 0.04)
    assert np.all(np.abs(c - p) <= 0.02 + 1e-12)
    assert np.allclose(c[0], [-0.02, 0.02, 0.06])
