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


def test_an_archive_that_cannot_be_written_stops_and_says_so_not_as_a_model_error(tmp_path, monkeypatch,
                                                                                   capsys) -> None:
    """A read-only or vanished map folder raised out of the sink: counted as 'mapping model calls failed',
    the run exited 0 with map.ply silently short of submaps."""
    monkeypatch.setattr(shutil, "disk_usage", lambda p: Usage(10**12, 0, 10**12))
    out = MapOutput(tmp_path, {"rig": {}, "model": {}, "config": {}}, voxel_m=0.25)
    subs = [make_submap(k, seed=k) for k in range(4)]
    writes = {"n": 0}
    commit = out.archive.commit

    def failing_commit(*args, **kwargs):
        writes["n"] += 1
        if writes["n"] == 3:
            raise PermissionError(13, "Permission denied", str(tmp_path / "map" / "submap_000002.npz"))
        return commit(*args, **kwargs)

    monkeypatch.setattr(out.archive, "commit", failing_commit)
    for k, sm in enumerate(subs):
        out.sink(SimpleNamespace(link=None, submap=sm, changed=[], version=k + 1), MappingStats())
    assert "the map archive stopped at map version 2" in capsys.readouterr().err
    summary = out.finish()
    assert summary["archive_stopped"]["reason"].startswith("the archive could not be written (Permission "
                                                            "denied")
    assert summary["archive_stopped"]["commits_skipped"] == 2 and summary["submaps"] == 2
    line = _mapping_line(MP, summary)
    assert "WARNING: the map archive stopped at map version 2 (the archive could not be written" in line
    assert "MB)" not in line
    assert check_integrity(tmp_path / "map") == []
    # a model call that outlives the end of the run: counted, never written into the closed archive
    out.sink(SimpleNamespace(link=None, submap=make_submap(9, seed=9), changed=[], version=9), MappingStats())
    assert out.late_commits == 1 and read_manifest(tmp_path / "map")["map_version"] == 2


def test_a_failed_export_leaves_the_rest_of_the_run_to_be_written(tmp_path, monkeypatch, capsys) -> None:
    """A full disk at map.ply raised out of the run: no trajectory, report or status was written."""
    import tools.map_archive as map_archive

    monkeypatch.setattr(shutil, "disk_usage", lambda p: Usage(10**12, 0, 10**12))
    out = MapOutput(tmp_path, {"rig": {}, "model": {}, "config": {}}, voxel_m=0.25)
    out.sink(SimpleNamespace(link=None, submap=make_submap(0, seed=0), changed=[], version=1), MappingStats())

    def full(*args, **kwargs):
        raise OSError(28, "No space left on device", str(tmp_path / "map.ply"))

    monkeypatch.setattr(map_archive, "export_map", full)
    summary = out.finish()
    assert summary["ply"] is None
    assert summary["export_error"] == f"{tmp_path / 'map.ply'}: No space left on device"
    assert "map.ply was not written" in capsys.readouterr().err
    assert "no map.ply: the export failed" in _mapping_line(MP, summary)
