"""A run's map archive stops, whole and readable, when the disk runs low: the later commits are counted and
the console warns, and room is left for the trajectory files written at the end. The export at the end of
a run says how far it is."""
from __future__ import annotations

import shutil
from collections import namedtuple
from types import SimpleNamespace

from test_map_archive import make_submap

from runtime.mapping.mapper import MappingStats
from tools.map_archive import check_integrity, read_manifest
from tools.run_map import MIN_FREE_MB, MapOutput
from tools.run_summary import mapping_line as _mapping_line

Usage = namedtuple("Usage", "total used free")
MP = {"windows_accepted": 5, "windows_offered": 5, "windows_dropped_queue": 0, "windows_rejected": {},
      "points_sampled": 1, "rejected_confidence": 0, "rejected_multiview": 0, "points_retained": 1}


def test_the_archive_stops_at_its_last_commit_when_the_disk_runs_low(tmp_path, monkeypatch) -> None:
    free = {"mb": 50_000.0}
    monkeypatch.setattr(shutil, "disk_usage", lambda p: Usage(10**12, 0, int(free["mb"] * 1e6)))
    out = MapOutput(tmp_path, {"rig": {}, "model": {}, "config": {}}, voxel_m=0.25)
    subs = [make_submap(k, seed=k) for k in range(5)]
    for k, sm in enumerate(subs):
        if k == 3:
            free["mb"] = MIN_FREE_MB - 1            # the disk fills up before the fourth commit
        if k == 4:
            free["mb"] = 50_000.0                   # space freed again: the archive stays stopped
        out.sink(SimpleNamespace(link=None, submap=sm, changed=[], version=k + 1), MappingStats())
    assert [e["index"] for e in read_manifest(tmp_path / "map")["submaps"]] == [0, 1, 2]
    assert check_integrity(tmp_path / "map") == []           # a whole, readable archive of the map so far
    summary = out.finish()
    assert summary["submaps"] == 3 and summary["map_version"] == 3 and summary["ply"] == "map.ply"
    stopped = summary["archive_stopped"]
    assert stopped == {"reason": f"less than {MIN_FREE_MB:g} MB free on the run's disk",
                       "free_mb": MIN_FREE_MB - 1, "map_version": 3, "commits_skipped": 2}
    line = _mapping_line(MP, summary)
    assert "WARNING: the map archive stopped at map version 3" in line and "2 later commits" in line


def test_plenty_of_space_archives_every_commit(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(shutil, "disk_usage", lambda p: Usage(10**12, 0, 10**12))
    out = MapOutput(tmp_path, {"rig": {}, "model": {}, "config": {}}, voxel_m=0.25)
    for k in range(2):
        out.sink(SimpleNamespace(link=None, submap=make_submap(k, seed=k), changed=[], version=k + 1),
                 MappingStats())
    summary = out.finish()
    assert summary["submaps"] == 2 and summary["archive_stopped"] is None
    assert "WARNING" not in _mapping_line(MP, summary)


def test_the_end_of_a_run_writes_the_manifest_whole_or_says_why_not(tmp_path, monkeypatch, capsys) -> None:
    """A finished run's archive is manifest.json alone; when that last write fails, the journal stays, the
    archive reads the same, and the summary and stderr say so."""
    import os
    from pathlib import Path

    real_replace = os.replace

    def failing_replace(src, dst):
        if Path(dst).name == "manifest.json":
            raise OSError("disk gone")
        return real_replace(src, dst)

    monkeypatch.setattr(shutil, "disk_usage", lambda p: Usage(10**12, 0, 10**12))
    for fail in (False, True):
        folder = tmp_path / str(fail)
        out = MapOutput(folder, {"rig": {}, "model": {}, "config": {}}, voxel_m=0.25)
        subs = [make_submap(k, seed=k, n_pts=40) for k in range(5)]
        for k, sm in enumerate(subs):
            out.sink(SimpleNamespace(link=None, submap=sm, changed=[], version=k + 1), MappingStats())
        lines = (folder / "map" / "manifest.journal").read_bytes().count(b"\n")   # the later commits
        assert lines >= 1
        if fail:
            monkeypatch.setattr(os, "replace", failing_replace)
        summary = out.finish()
        monkeypatch.undo()
        monkeypatch.setattr(shutil, "disk_usage", lambda p: Usage(10**12, 0, 10**12))
        assert (folder / "map" / "manifest.journal").exists() == fail
        info = read_manifest(folder / "map")
        assert info["map_version"] == 5 and info["journal"]["commits"] == (lines if fail else 0)
        npz = sum((folder / "map" / e["file"]).stat().st_size for e in info["submaps"])
        assert summary["archive_written_mb"]["submaps"] == round(npz / 1e6, 3)
        assert (summary["archive_journal_left"] is not None) == fail
        assert ("was left with its journal (disk gone)" in capsys.readouterr().err) == fail


def test_a_long_export_at_the_end_of_a_run_says_how_far_it_is(tmp_path, monkeypatch, capsys) -> None:
    from tools import run_map

    monkeypatch.setattr(shutil, "disk_usage", lambda p: Usage(10**12, 0, 10**12))
    out = MapOutput(tmp_path, {"rig": {}, "model": {}, "config": {}}, voxel_m=0.25)
    for k in range(4):
        out.sink(SimpleNamespace(link=None, submap=make_submap(k, seed=k), changed=[], version=k + 1),
                 MappingStats())
    clock = iter(range(0, 1000, 3))                  # 3 s of wall time between calls
    monkeypatch.setattr(run_map.time, "monotonic", lambda: float(next(clock)))
    assert out.finish()["submaps"] == 4
    err = capsys.readouterr().err
    # one line at most every 5 s, none for the last submap (the export is then done)
    assert err.splitlines() == ["  exporting map.ply: 2/4 submaps fused (6 s)"]


def test_the_summary_says_why_a_run_has_no_map_ply() -> None:
    """A run too short for one window wrote no map.ply; the line said "0 voxels in map.ply"."""
    none_offered = dict(MP, windows_accepted=0, windows_offered=0, points_retained=0)
    config = {"window_images": 5, "keyframe_spacing_s": 0.5}
    line = _mapping_line(none_offered, {"ply": None, "voxels": 0}, config)
    assert "map.ply:" in line and "no window was complete" in line and "5 keyframes 0.5 s apart" in line
    assert ", 2 s;" in line and "voxels in map.ply" not in line
    rejected = dict(MP, windows_accepted=0, windows_rejected={"fit_rmse": 5}, points_retained=0)
    assert "no map.ply (nothing was mapped)" in _mapping_line(rejected, {"ply": None, "voxels": 0}, config)
    assert "1234 voxels in map.ply" in _mapping_line(MP, {"ply": "map.ply", "voxels": 1234}, config)
