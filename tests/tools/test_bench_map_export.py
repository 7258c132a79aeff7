"""`davio bench map-export`: the corridor archive fuses to the same voxels with today's grid and with the
former join-every-submap one, each new submap adds voxels, and the table and JSON say so."""
from __future__ import annotations

import json

import numpy as np
import pytest

from tools.cli import main


def test_map_export_bench_fuses_the_same_voxels_both_ways(tmp_path, capsys) -> None:
    out = tmp_path / "export.json"
    assert main(["bench", "map-export", "--submaps", "3,6", "--anchor-max", "6", "--max-depth", "4",
                 "--dir", str(tmp_path / "arch"), "--out", str(out)]) == 0
    table = capsys.readouterr().out
    assert "| 3 (0.00 h) |" in table and "| 6 (0.00 h) |" in table
    res = json.loads(out.read_text())
    rows = res["rows"]
    assert res["same_voxels"] and all(r["same_voxels"] for r in rows)
    assert [r["submaps"] for r in rows] == [3, 6]
    assert rows[1]["points"] == 2 * rows[0]["points"] > 0
    assert rows[1]["grid"]["voxels"] > rows[0]["grid"]["voxels"] > 0      # the corridor keeps adding walls
    assert all(r["anchor"]["voxels"] == r["grid"]["voxels"] for r in rows)


def test_corridor_submap_points_lie_on_the_corridor_walls() -> None:
    """The bench's synthetic depths (2 % noise) put every point within 2 % x 5 sigma of its range off the
    corridor's walls, floor or ceiling, in the world frame (T_OS T_SC of each image)."""
    from tools.benchmarks.map_export import CORRIDOR_Y, CORRIDOR_Z, corridor_submap

    sm = corridor_submap(4, np.random.default_rng(0), max_depth=6.0)
    p = sm.points_M()
    d_wall = np.minimum(np.abs(p[:, 1] - CORRIDOR_Y), np.abs(p[:, 1] + CORRIDOR_Y))
    d_floor = np.minimum(np.abs(p[:, 2] - CORRIDOR_Z[0]), np.abs(p[:, 2] - CORRIDOR_Z[1]))
    rng_m = np.linalg.norm(sm.points_C.astype(float), axis=1)
    assert np.all(np.minimum(d_wall, d_floor) <= 0.1 * rng_m + 1e-6)
    assert sm.n_points > 50_000 and np.ptp(p[:, 0]) > 4.0


@pytest.mark.parametrize("argv, message", [
    (["--submaps", "6,3"], "increasing"), (["--submaps", "x"], "integers"),
    (["--voxel", "0"], "--voxel: must be >= 0.0001"), (["--voxel", "1e-300"], "--voxel: must be >= 0.0001")])
def test_map_export_bench_refuses_bad_options(argv, message, capsys) -> None:
    with pytest.raises(SystemExit) as info:
        main(["bench", "map-export", *argv])
    assert message in str(info.value.code) + capsys.readouterr().err
