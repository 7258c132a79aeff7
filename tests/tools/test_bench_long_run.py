"""`davio bench long-run`: the JSON it writes, the archive read back as the whole manifest and the bytes a
commit of its journal against the whole manifest's, and the bytes per pose of the columns against the
objects (tracemalloc), on a small run."""
from __future__ import annotations

import json

import pytest

from tools.cli import main


def test_long_run_bench_measures_both_costs(tmp_path, capsys) -> None:
    out = tmp_path / "long.json"
    assert main(["bench", "long-run", "--hours", "0.05,0.1", "--poses", "8192", "--moved", "20",
                 "--writer-submaps", "300", "--track-seconds", "0", "--out", str(out)]) == 0
    table = capsys.readouterr().out
    assert "| 0.05 h | 120 |" in table and "| 0.1 h | 240 |" in table
    res = json.loads(out.read_text())
    rows = res["manifest"]
    assert [r["submaps"] for r in rows] == [120, 240]
    assert all(r["same_text"] and r["reads_back"] and r["complete_cycle"] for r in rows)
    assert rows[1]["manifest_mb"] > rows[0]["manifest_mb"] > 0
    for r in rows:
        # a cycle's journal grows to the manifest's size, then the manifest is written once: on average a
        # commit writes about twice the manifest over the cycle's commits, less than the whole manifest
        whole = r["whole_bytes_per_commit"]
        assert r["cycle_commits"] >= 2 and whole == pytest.approx(1e6 * r["manifest_mb"])
        n = r["cycle_commits"]
        assert 1.5 * whole / n <= r["bytes_per_commit"] <= 2.5 * whole / (n - 1)
    assert rows[1]["bytes_per_commit"] < 0.3 * rows[1]["whole_bytes_per_commit"]
    p = res["poses"]
    # 8192 poses fill two whole chunks of 254-byte rows; the objects were about 1.4 kB a pose
    assert 254 <= p["columns_bytes_per_pose"] < 300 and p["objects_bytes_per_pose"] > 1000
    assert p["columns_mb_per_hour"] == pytest.approx(p["columns_bytes_per_pose"] * 72000 / 1e6)
    # the writer keeps each entry as its encoded text only (with the dicts beside them it held 3.4x the
    # texts, 4.9 kB a submap): what it holds a submap is the texts and their bookkeeping
    w = res["writer"]
    # (the texts are 98.6 % of the traced bytes alone; memory another thread of the test process frees while
    # tracemalloc runs is subtracted from them: traced came out 0.6 % below the texts under the full suite)
    assert w["submaps"] == 300 and 1000 < w["text_bytes_per_submap"] < 1.1 * w["traced_bytes_per_submap"]
    assert w["traced_bytes_per_submap"] < 2.5 * w["text_bytes_per_submap"]
    assert "map archive writer (300 submaps" in table
    assert res["tracking"] is None                     # --track-seconds 0: the whole-pipeline run skipped


@pytest.mark.parametrize("argv, message", [
    (["--hours", "0"], "--hours must lie in (0, 24]"),
    (["--hours", "a,b"], "--hours must be numbers"),
    (["--camera-hz", "nan"], "argument --camera-hz: 'nan' is not a finite number"),
    (["--camera-hz", "0"], "--camera-hz must be positive"),
    (["--poses", "5"], "argument --poses: must be >= 100, got 5"),
    (["--moved", "-1"], "argument --moved: must be >= 0, got -1"),
    (["--writer-submaps", "10"], "argument --writer-submaps: must be from 200 to 100000, got 10"),
    (["--writer-submaps", "1_000"], "argument --writer-submaps: '1_000' is not a whole number"),
    (["--track-seconds", "5"], "--track-seconds must be 0 or in [10, 3600]"),
])
def test_long_run_bench_refuses_bad_arguments(argv, message, capsys) -> None:
    with pytest.raises(SystemExit) as info:
        main(["bench", "long-run", *argv])
    assert message in str(info.value.code) + capsys.readouterr().err
