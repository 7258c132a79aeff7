"""`davio map export|view|info` on what users do to files: outputs that must not be replaced, damaged
archives (refused, or left out with --skip-damaged and said), manifest values of the wrong type, a run
without a map. Expected values come from the archive written here (brute-force fusion of the submaps
that are kept), not from the code under test.
"""
from __future__ import annotations

import json
import os
import stat
from pathlib import Path

import numpy as np
import pytest

from runtime.errors import DataError
from runtime.files import sha256_file
from tests.tools.test_map_archive import VOXEL, assert_fusion_equals, brute_force_fusion, write_two_commits
from tools.cli import main
from tools.map_archive import fuse_archive, map_info, read_manifest


@pytest.fixture
def run(tmp_path: Path) -> tuple[Path, list]:
    _, subs = write_two_commits(tmp_path / "run" / "map")
    (tmp_path / "run" / "run_status.json").write_text('{"status": "complete"}')
    return tmp_path / "run", subs


def _edit_manifest(folder: Path, edit) -> None:
    path = folder / "manifest.json"
    info = json.loads(path.read_text())
    edit(info)
    path.write_text(json.dumps(info))


def test_export_refuses_to_replace_what_is_not_its_own_output(run, tmp_path: Path, capsys) -> None:
    folder, _ = run
    manifest = (folder / "map" / "manifest.json").read_bytes()
    (folder / "report.json").write_text("{}")
    cases = [
        (folder / "report.json", "expected a .ply file"),
        (folder / "map" / "x.ply", "lies inside"),               # inside the archive it reads
        (tmp_path / "newdir", "expected a .ply file"),           # `newdir/` with the slash stripped
        (tmp_path / "missing" / "m.ply", "does not exist"),
    ]
    for target, why in cases:
        assert main(["map", "export", str(folder), "--out", str(target), "--overwrite"]) == 1
        assert why in capsys.readouterr().err, target
    fifo = tmp_path / "pipe.ply"
    os.mkfifo(fifo)
    assert main(["map", "export", str(folder), "--out", str(fifo), "--overwrite"]) == 1
    assert "is not a regular file" in capsys.readouterr().err and stat.S_ISFIFO(os.stat(fifo).st_mode)
    mine = tmp_path / "mine.ply"
    mine.write_text("keep me")
    assert main(["map", "export", str(folder), "--out", str(mine)]) == 1
    assert "exists; pass --overwrite" in capsys.readouterr().err and mine.read_text() == "keep me"
    assert main(["map", "view", str(folder), "--out", str(tmp_path / "v.png")]) == 0
    assert main(["map", "view", str(folder), "--out", str(tmp_path / "v.png")]) == 1
    assert "exists; pass --overwrite" in capsys.readouterr().err
    assert main(["map", "export", str(folder), "--out", str(mine), "--overwrite"]) == 0
    assert mine.read_bytes().startswith(b"ply\n")
    # the run's own map.ply is the default output: written, then replaced (and said)
    assert main(["map", "export", str(folder)]) == 0
    assert main(["map", "export", str(folder)]) == 0
    assert "(replaced)" in capsys.readouterr().out
    assert (folder / "map" / "manifest.json").read_bytes() == manifest
    assert (folder / "report.json").read_text() == "{}"


def test_damaged_file_is_refused_or_left_out_and_said(run, capsys) -> None:
    folder, subs = run
    npz = folder / "map" / "submap_000001.npz"
    data = dict(np.load(npz))
    data["points_C"] = data["points_C"] * 3   # a valid file with other content: only the checksum knows
    with open(npz, "wb") as fh:
        np.savez(fh, **data)
    for action in ("export", "view"):
        assert main(["map", action, str(folder)]) == 1
        err = capsys.readouterr().err
        assert "damaged archive: submap_000001.npz" in err and "--skip-damaged" in err
    assert not (folder / "map.ply").exists()
    fuse_archive(folder / "map", VOXEL, verify=False)   # the run's own export skips the second read
    assert main(["map", "export", str(folder), "--skip-damaged"]) == 0
    assert "1 damaged submap file(s) left out: submap_000001.npz" in capsys.readouterr().err
    notes: list[str] = []
    kept = fuse_archive(folder / "map", VOXEL, skip_damaged=True, notes=notes)
    assert_fusion_equals(kept, brute_force_fusion([subs[0], subs[2]], VOXEL), VOXEL)
    assert len(notes) == 1


@pytest.mark.parametrize("key,value,why", [
    ("lam", None, "lam is null"),                      # what the writer writes for a non-finite state
    ("lam", float("nan"), "lam is nan"),               # hand-edited: JSON readers accept NaN and Infinity
    ("lam", 1e300, "lam is 1e+300"),
    ("lam", 10**30, f"lam is {10**30}"),               # an integer: np.isfinite raised TypeError
    ("lam", 10**400, f"lam is {10**400}"),             # beyond a float: float() raised OverflowError
    ("T_MS", [[10**400, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "T_MS is not numeric"),
    ("T_MS", np.eye(3).tolist(), "T_MS has shape (3, 3)"),                 # said by load_submap
    ("T_MS", np.zeros((4, 4)).tolist(), "T_MS: last row must be [0, 0, 0, 1]"),   # every point in one voxel
    ("T_MS", np.diag([1.0, 1.0, -1.0, 1.0]).tolist(), "T_MS: rotation part is a reflection"),
    ("T_MS", [[1.0, 0, 0, 1e300], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1]], "T_MS: translation beyond"),
])
def test_a_state_that_places_no_point_is_a_problem_and_left_out_with_a_note(run, capsys, key, value,
                                                                          why) -> None:
    folder, subs = run

    def edit(info: dict) -> None:
        info["submaps"][1][key] = value

    _edit_manifest(folder / "map", edit)
    info = map_info(folder / "map")
    assert len(info["problems"]) == 1 and why in info["problems"][0]
    assert "submap_000001.npz" in info["problems"][0] or "submap 1 T_MS" in info["problems"][0]
    assert info["points_placed"] == len(subs[0].points_C) + len(subs[2].points_C)
    assert main(["map", "info", str(folder)]) == 1
    notes: list[str] = []
    fused = fuse_archive(folder / "map", VOXEL, notes=notes)
    assert_fusion_equals(fused, brute_force_fusion([subs[0], subs[2]], VOXEL), VOXEL)
    assert notes == ["1 submap(s) whose graph state places no point (not finite, or not a rigid transform: "
                     f"`davio map info` says which) left out ({len(subs[1].points_C)} points): "
                     "submap_000001.npz"]


@pytest.mark.parametrize("edit,message", [
    (lambda m: m["submaps"][0].__setitem__("segment", "a"), "submaps[0].segment is 'a', expected an integer"),
    (lambda m: m.__setitem__("pairs", 5), "'pairs' is 5, expected a list"),
    (lambda m: m["submaps"][1].__setitem__("lam", "x"), "submaps[1].lam is 'x', expected a number"),
    (lambda m: m["submaps"][1].__setitem__("fit", [1, 2]), "submaps[1].fit is [1, 2], expected an object"),
])
def test_manifest_values_of_the_wrong_type_name_the_manifest(run, capsys, edit, message: str) -> None:
    folder, _ = run
    _edit_manifest(folder / "map", edit)
    with pytest.raises(DataError, match="manifest.json: " + message.replace("[", r"\[").replace("]", r"\]")):
        read_manifest(folder / "map")
    assert main(["map", "info", str(folder)]) == 1
    assert message in capsys.readouterr().err


def test_a_scalar_array_of_the_wrong_shape_names_the_file(run, capsys) -> None:
    folder, _ = run
    npz = folder / "map" / "submap_000002.npz"
    data = dict(np.load(npz))
    data["index"] = np.array([2, 2])
    with open(npz, "wb") as fh:
        np.savez(fh, **data)
    assert main(["map", "export", str(folder), "--skip-damaged"]) == 0   # the checksum catches it first
    capsys.readouterr()
    _edit_manifest(folder / "map", lambda m: m["submaps"][2].update(bytes=npz.stat().st_size,
                                                                     sha256=sha256_file(npz)))
    assert main(["map", "export", str(folder), "--overwrite"]) == 1
    assert "submap_000002.npz: array 'index' holds 2 values, expected one" in capsys.readouterr().err


def test_run_without_a_map_and_info_voxels(run, tmp_path: Path, capsys) -> None:
    folder, subs = run
    bare = tmp_path / "native_run"
    bare.mkdir()
    (bare / "run_status.json").write_text('{"status": "complete"}')
    (bare / "odometry.tum").write_text("")
    assert main(["map", "info", str(bare)]) == 1
    assert "run folder without a map/: the run was made without a depth model" in capsys.readouterr().err
    assert main(["map", "info", str(folder), "--json", "--voxel", str(VOXEL)]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["voxels"] == len(brute_force_fusion(subs, VOXEL))
    assert main(["map", "info", str(folder), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["voxels"] is None


def _two_segment_subs() -> list:
    """Submaps after one filter reset: 0 and 1 in segment 0; 2, 3 and 4 in segment 1 (its own map frame:
    fusing both would overlay unrelated maps), 3 and 4 with a graph state that places nothing (NaN, written
    as null). Segment 0 has the most placeable submaps, though neither the most submaps nor the last."""
    from tests.tools.test_map_archive import make_submap

    subs = [make_submap(k, seed=k) for k in range(5)]
    for sm in subs[2:]:
        sm.segment = 1
    for sm in subs[3:]:
        sm.T_MS = np.full((4, 4), np.nan)
    return subs


def _two_segment_run(folder: Path) -> list:
    from tests.tools.test_map_archive import HEADER
    from tools.map_archive import MapArchiveWriter

    subs = _two_segment_subs()
    w = MapArchiveWriter(folder / "map", HEADER)
    w.commit(subs, pairs=[{"a": 0, "b": 1}], version=1, stats={})
    w.close()
    (folder / "run_status.json").write_text('{"status": "complete"}')
    return subs


def _ply_voxels(path: Path, subs: list) -> None:
    """The PLY holds exactly the brute-force fusion of `subs`."""
    from tools.evaluation.ply import read_ply_vertices

    got = read_ply_vertices(path)
    expected = brute_force_fusion(subs, VOXEL)
    assert len(got) == len(expected)
    np.testing.assert_allclose(np.sort(got[:, 0]), np.sort([v[0][0] for v in expected.values()]), atol=1e-5)


def test_a_map_of_several_filter_segments_exports_one_segment_and_says_so(tmp_path: Path, capsys) -> None:
    folder = tmp_path / "run"
    subs = _two_segment_run(folder)
    assert main(["map", "export", str(folder), "--voxel", str(VOXEL)]) == 0
    err = capsys.readouterr().err
    assert "the map holds 2 filter segments, each in its own frame" in err
    assert "0 (2 submaps), 1 (1 submaps); segment 0, the largest, is used (--segment K picks another)" in err
    _ply_voxels(folder / "map.ply", subs[:2])
    seg1 = tmp_path / "seg1.ply"
    assert main(["map", "export", str(folder), "--voxel", str(VOXEL), "--segment", "1",
                 "--out", str(seg1)]) == 0
    err = capsys.readouterr().err
    assert "2 submap(s) of other filter segments left out" in err and "the largest" not in err
    _ply_voxels(seg1, subs[2:3])
    assert main(["map", "export", str(folder), "--segment", "7", "--out", str(tmp_path / "x.ply")]) == 1
    assert "no submap of filter segment 7 (segments: 0 (2 submaps), 1 (1 submaps))" in capsys.readouterr().err
    assert not (tmp_path / "x.ply").exists()
    assert main(["map", "view", str(folder), "--segment", "1"]) == 0
    assert main(["map", "view", str(folder), "--overwrite"]) == 0
    assert "segment 0, the largest, is used" in capsys.readouterr().err


def test_a_run_whose_filter_was_reset_writes_map_ply_of_its_largest_segment(tmp_path: Path) -> None:
    from types import SimpleNamespace

    from runtime.mapping.mapper import MappingStats
    from tests.tools.test_map_archive import HEADER
    from tools.run_map import MapOutput
    from tools.run_summary import mapping_line

    subs = _two_segment_subs()
    out = MapOutput(tmp_path, HEADER, voxel_m=VOXEL)
    for k, sm in enumerate(subs):
        out.sink(SimpleNamespace(link=None, submap=sm, changed=[], version=k + 1), MappingStats())
    summary = out.finish()
    assert summary["ply"] == "map.ply" and summary["ply_segment"] == 0
    assert summary["segment_submaps"] == {"0": 2, "1": 1}
    _ply_voxels(tmp_path / "map.ply", subs[:2])
    from tools.evaluation.ply import ply_comments

    assert ply_comments(tmp_path / "map.ply") == ["davio map", "segment 0"]      # what `eval surface` reads
    # a run reset after its only mapped segment: the archive holds one segment, and the PLY still says which
    one = MapOutput(tmp_path / "one", HEADER, voxel_m=VOXEL)
    one.sink(SimpleNamespace(link=None, submap=subs[2], changed=[], version=1), MappingStats())
    assert one.finish()["ply_segment"] is None
    assert ply_comments(tmp_path / "one" / "map.ply") == ["davio map", "segment 1"]
    mp = {"windows_accepted": 5, "windows_offered": 5, "windows_dropped_queue": 0, "windows_rejected": {},
          "points_sampled": 1, "rejected_confidence": 0, "rejected_multiview": 0, "points_retained": 1}
    line = mapping_line(mp, summary)
    assert (f"{summary['voxels']} voxels in map.ply, of filter segment 0 (2 of 3 submaps; its trajectory: "
            "final_segment0.tum)") in line
    assert "`davio map export RUN --segment K --out FILE.ply`" in line


def test_map_info_counts_each_segments_voxels_apart_and_names_the_one_used(tmp_path: Path, capsys) -> None:
    """`map info --voxel` fused every segment into one grid: a count of overlaid unrelated frames that
    matched no map.ply."""
    folder = tmp_path / "run"
    subs = _two_segment_run(folder)
    info = map_info(folder / "map", VOXEL)
    assert info["main_segment"] == 0 and info["segment_submaps"] == {"0": 2, "1": 1}
    assert info["voxels"] == len(brute_force_fusion(subs[:2], VOXEL)) == info["voxels_by_segment"]["0"]
    assert info["voxels_by_segment"]["1"] == len(brute_force_fusion(subs[2:3], VOXEL))
    assert main(["map", "export", str(folder), "--voxel", str(VOXEL)]) == 0
    from tools.evaluation.ply import read_ply_vertices

    assert len(read_ply_vertices(folder / "map.ply")) == info["voxels"]
    capsys.readouterr()
    assert main(["map", "info", str(folder), "--voxel", str(VOXEL)]) == 1     # unplaceable states: problems
    out = capsys.readouterr().out
    assert "segments     0 (2 placeable), 1 (1 placeable): each in its own frame" in out
    assert f"voxels       {info['voxels']} (segment 0; by segment: 0: " in out
