"""The tracker's greedy corner choice (numba) against the plain description of the rule."""
from __future__ import annotations

import numpy as np
import pytest

from runtime.msckf.corner_grid import choose_corners


def _reference(uv: np.ndarray, occupied: np.ndarray, count: np.ndarray, quota: int, n_wanted: int,
               cell: float, w: int, h: int) -> list[int]:
    """Strongest first: skip a corner whose occupancy cell is taken; pass 1 honours the per-cell quota,
    pass 2 does not; a taken corner blocks its 3x3 occupancy neighbourhood."""
    occupied, count = occupied.copy(), count.copy()
    gy, gx = count.shape
    out: list[int] = []
    for use_quota in (True, False):
        for k, (u, v) in enumerate(uv):
            if len(out) >= n_wanted:
                break
            ox, oy = int(np.floor(u / cell)), int(np.floor(v / cell))
            if occupied[oy, ox]:
                continue
            cx, cy = min(int(np.floor(u * gx / w)), gx - 1), min(int(np.floor(v * gy / h)), gy - 1)
            if use_quota and count[cy, cx] >= quota:
                continue
            count[cy, cx] += 1
            occupied[max(oy - 1, 0):oy + 2, max(ox - 1, 0):ox + 2] = True
            out.append(k)
    return out


@pytest.mark.parametrize("seed", range(6))
def test_choice_matches_the_rule(seed: int) -> None:
    rng = np.random.default_rng(seed)
    w, h, cell = 752, 480, 10.0
    occupied = rng.random((int(np.ceil(h / cell)) + 1, int(np.ceil(w / cell)) + 1)) < 0.3
    count = rng.integers(0, 12, (5, 5))
    uv = np.column_stack([rng.uniform(5, w - 5, 400), rng.uniform(5, h - 5, 400)])
    quota, n_wanted = 8, int(rng.integers(5, 120))
    expected = _reference(uv, occupied, count, quota, n_wanted, cell, w, h)
    occ, cnt = occupied.copy(), count.copy()
    got = choose_corners(uv, occ, cnt, quota, n_wanted, cell, w, h)
    assert got.tolist() == expected
    assert len(expected) <= n_wanted
    # the chosen corners are min_px_dist apart in occupancy cells and the grid counts went up by them
    cells = np.floor(uv[got] / cell).astype(int)
    assert np.all(np.max(np.abs(cells[:, None] - cells[None]), axis=2)[~np.eye(len(got), dtype=bool)] >= 2)
    assert cnt.sum() == count.sum() + len(got)


def test_existing_tracks_block_their_neighbourhood() -> None:
    """Each pixel blocks its occupancy cell and the eight around it, clipped at the grid's edges."""
    from runtime.msckf.corner_grid import block_neighbourhoods

    rng = np.random.default_rng(1)
    cell, shape = 10.0, (49, 77)
    uv = np.column_stack([rng.uniform(0, 770, 60), rng.uniform(0, 490, 60)])
    uv[:2] = [[0.5, 0.5], [769.0, 489.0]]                   # corners of the grid
    uv[2:4] = [[-25.0, 100.0], [900.0, 600.0]]               # beyond it: its border cells
    expected = np.zeros(shape, dtype=bool)
    for u, v in uv:
        ox = min(max(int(u // cell), 0), shape[1] - 1)
        oy = min(max(int(v // cell), 0), shape[0] - 1)
        expected[max(oy - 1, 0):oy + 2, max(ox - 1, 0):ox + 2] = True
    got = np.zeros(shape, dtype=bool)
    block_neighbourhoods(got, uv, cell)
    np.testing.assert_array_equal(got, expected)
