"""`davio map` on inputs a user damaged or cannot read: an edited alignment.json, a file given for the run
folder, and files the process may not read (simulated: the tests run as root, where chmod does not stop a
read) give one clear line naming the input, not a traceback or a blame on --out."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from runtime.errors import DataError
from tests.tools.test_map_align import T_NW, T_PW, _sessions, _write_session
from tests.tools.test_map_command import run  # noqa: F401  (the fixture)
from tools.cli import main


@pytest.fixture
def aligned(tmp_path: Path) -> Path:
    prior_views, new_views = _sessions(T_PW, T_NW)
    _write_session(tmp_path / "prior", prior_views)
    _write_session(tmp_path / "new", new_views)
    assert main(["map", "align", str(tmp_path / "new"), "--to", str(tmp_path / "prior")]) == 0
    return tmp_path / "new"


@pytest.mark.parametrize("key,value,message", [
    ("localized", "no", "was not localised in the prior map"),          # a string is not true
    ("T_PN", np.zeros((4, 4)).tolist(), "T_PN last row must be [0, 0, 0, 1]"),   # the map in one voxel
    ("T_PN", np.diag([1.0, 1.0, -1.0, 1.0]).tolist(), "T_PN rotation part is a reflection"),
    ("T_PN", [[float("nan")] * 4] * 4, "T_PN contains non-finite numbers"),
    ("new_segment", 1.5, "new_segment and prior_segment must be integers, got 1.5"),
    ("prior_segment", True, "must be integers, got 0, True"),
    ("new_segment", float("inf"), "must be integers, got inf"),          # int() raised OverflowError
    ("T_PN", [[10**400, 0, 0, 0]] + np.eye(4)[1:].tolist(), "not a davio alignment (OverflowError"),
])
def test_an_edited_alignment_is_refused_naming_what_is_wrong(aligned: Path, capsys, key, value,
                                                             message: str) -> None:
    path = aligned / "alignment.json"
    al = json.loads(path.read_text())
    al[key] = value
    path.write_text(json.dumps(al))
    assert main(["map", "export", str(aligned), "--in-prior"]) == 1
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1, err
    assert not (aligned / "map.prior.ply").exists()


def test_a_file_given_for_the_run_folder_is_said_to_be_one(run, capsys) -> None:  # noqa: F811
    folder, _ = run
    ply = folder / "map.ply"
    assert main(["map", "export", str(folder)]) == 0
    capsys.readouterr()
    assert main(["map", "export", str(ply)]) == 1      # before: "--out .../map.ply: exists; pass --overwrite"
    err = capsys.readouterr().err
    assert f"{ply}: not a folder: give the run folder" in err and "--overwrite" not in err


def _deny(monkeypatch, target: Path) -> None:
    """Reading `target` fails as it does for a file the user may not read."""
    real_open = open
    real_read_text = Path.read_text

    def guarded_open(file, *a, **k):
        if Path(file) == target:
            raise PermissionError(13, "Permission denied", str(file))
        return real_open(file, *a, **k)

    def guarded_read_text(self, *a, **k):
        if self == target:
            raise PermissionError(13, "Permission denied", str(self))
        return real_read_text(self, *a, **k)

    monkeypatch.setattr("builtins.open", guarded_open)
    monkeypatch.setattr(Path, "read_text", guarded_read_text)


def test_an_unreadable_manifest_is_one_line(run, capsys, monkeypatch) -> None:  # noqa: F811
    folder, _ = run
    _deny(monkeypatch, folder / "map" / "manifest.json")
    for cmd in (["map", "info", str(folder)], ["map", "export", str(folder), "--out", str(folder / "x.ply")]):
        assert main(cmd) == 1
        err = capsys.readouterr().err
        assert "manifest.json: manifest unreadable: Permission denied" in err and "--out" not in err, err
    with pytest.raises(DataError, match="manifest unreadable"):
        from tools.map_archive import read_manifest

        read_manifest(folder / "map")


def test_an_unreadable_submap_file_is_a_named_problem(run, capsys, monkeypatch) -> None:  # noqa: F811
    folder, _ = run
    _deny(monkeypatch, folder / "map" / "submap_000001.npz")
    assert main(["map", "info", str(folder)]) == 1
    assert "submap_000001.npz: unreadable (Permission denied)" in capsys.readouterr().out
    assert main(["map", "export", str(folder), "--out", str(folder / "x.ply")]) == 1
    err = capsys.readouterr().err
    assert "damaged archive: submap_000001.npz: unreadable (Permission denied)" in err and "--out" not in err


@pytest.mark.parametrize("failing,said", [
    ("map/submap_000000.npz", "cannot read {folder}/map/submap_000000.npz (Permission denied)"),
    (".x.ply.tmp", "--out {folder}/x.ply: cannot write (Permission denied)"),     # the atomic write's temp
    (None, "--out {folder}/x.ply: cannot write (Permission denied)"),
])
def test_an_os_error_in_an_export_blames_the_file_it_names(run, capsys, monkeypatch, failing, said) -> None:  # noqa: F811
    folder, _ = run

    def export_map(*a, **k):
        raise PermissionError(13, "Permission denied", None if failing is None else str(folder / failing))

    monkeypatch.setattr("tools.map_archive.export.export_map", export_map)
    assert main(["map", "export", str(folder), "--out", str(folder / "x.ply")]) == 1
    assert said.format(folder=folder) in capsys.readouterr().err


def test_non_finite_points_in_a_file_are_a_problem_and_counted_in_the_export(tmp_path: Path, capsys) -> None:
    """The writer keeps finite points only: NaN in a file whose hash matches was a silent drop."""
    from tests.tools.test_map_archive import HEADER, make_submap
    from tools.map_archive import MapArchiveWriter, fuse_archive, map_info

    subs = [make_submap(k, seed=k) for k in range(2)]
    subs[1].T_SC[0, 0, 3] = np.nan                 # every point of image 0 of submap 1
    lost = int((subs[1].image == 0).sum())
    MapArchiveWriter(tmp_path / "map", HEADER).commit(subs, [], 1, {})
    info = map_info(tmp_path / "map")
    assert info["problems"] == [f"submap_000001.npz: {lost} of its 400 points are not finite (NaN or Inf "
                                "depths or image poses in the file): they are left out"]
    assert info["points_placed"] == 800 - lost
    notes: list[str] = []
    fuse_archive(tmp_path / "map", 0.1, notes=notes)
    assert notes == [f"{lost} points that are not finite left out (NaN or Inf depths or image poses in "
                     "submap_000001.npz; `davio map info` lists them)"]


def test_a_camera_matrix_without_focal_lengths_is_refused_by_name(tmp_path: Path) -> None:
    from tests.tools.test_map_archive import HEADER, make_submap
    from tools.map_archive import MapArchiveWriter, map_info

    sm = make_submap(0, seed=0)
    sm.K = np.zeros((3, 3))
    with np.errstate(divide="ignore", invalid="ignore"):
        MapArchiveWriter(tmp_path / "map", HEADER).commit([sm], [], 1, {})
    info = map_info(tmp_path / "map")          # before: divide-by-zero warnings, then points dropped unsaid
    assert len(info["problems"]) == 1 and "K is not a camera matrix" in info["problems"][0]


def test_a_segment_other_than_the_aligned_one_is_refused(aligned: Path, capsys) -> None:
    """The alignment holds for the segment it was fitted on; an alignment.json of an older davio does not
    name it, and any --segment was then taken."""
    path = aligned / "alignment.json"
    al = json.loads(path.read_text())
    assert main(["map", "export", str(aligned), "--in-prior", "--segment", "3"]) == 1
    assert f"the alignment to the prior map holds for segment {al['new_segment']}" in capsys.readouterr().err
    del al["new_segment"], al["prior_segment"]
    path.write_text(json.dumps(al))
    assert main(["map", "export", str(aligned), "--in-prior", "--segment", "0"]) == 1
    assert "does not name: align the run again" in capsys.readouterr().err
    assert main(["map", "export", str(aligned), "--merge-prior", "--voxel", "0.25"]) == 0
    assert not (aligned / "map.prior.ply").exists() and (aligned / "map.merged.ply").is_file()


def test_an_alignment_is_refused_for_maps_other_than_the_aligned_ones(aligned: Path, tmp_path: Path,
                                                                    capsys) -> None:
    """alignment.json names the prior by path: a prior replaced at that path since (re-run with --overwrite),
    or an alignment written into another run's folder (`map align X --out OTHER`), merged unrelated maps
    without a word."""
    import shutil

    prior = tmp_path / "prior"
    al = json.loads((aligned / "alignment.json").read_text())
    assert al["prior_id"] and al["new_id"] and al["prior_id"] != al["new_id"]
    other = tmp_path / "other"
    prior_views, _ = _sessions(T_PW, T_NW)
    _write_session(other, prior_views)                       # the same views: another archive all the same
    shutil.copy(aligned / "alignment.json", other / "alignment.json")
    assert main(["map", "export", str(other), "--in-prior"]) == 1
    assert "aligns another map" in capsys.readouterr().err and not (other / "map.prior.ply").exists()
    shutil.rmtree(prior / "map")
    shutil.copytree(other / "map", prior / "map")           # the prior re-run at the same path
    for how in ("--in-prior", "--merge-prior"):
        assert main(["map", "export", str(aligned), how]) == 1
        assert "is not the map this run was aligned to (it was replaced since" in capsys.readouterr().err
    # an alignment of a davio that recorded no ids (or of a prior that had none), and a prior that has one
    # now: written after the alignment, so replaced (an old prior's re-run was merged in the wrong frame)
    old = {k: v for k, v in al.items() if k not in ("prior_id", "new_id")}
    (aligned / "alignment.json").write_text(json.dumps(old))
    assert main(["map", "export", str(aligned), "--merge-prior"]) == 1
    assert "it has an archive id, written after alignment.json, which records none" in capsys.readouterr().err


def test_a_prior_map_in_the_runs_own_out_is_refused(aligned: Path, tmp_path: Path, capsys) -> None:
    """`--prior-map runA --out runA --overwrite` replaced the map it localised in (its only copy)."""
    prior = tmp_path / "prior"
    manifest = (prior / "map" / "manifest.json").read_bytes()
    for out, given in ((prior, prior), (prior, prior / "map"), (tmp_path / "z", tmp_path / "z.partial")):
        assert main(["run", str(tmp_path / "rec"), "--emulated", "--prior-map", str(given), "--out", str(out),
                     "--overwrite"]) == 1
        assert "lies in this run's --out" in capsys.readouterr().err
    assert (prior / "map" / "manifest.json").read_bytes() == manifest
