"""`davio map align NEW --to PRIOR` on archives written here: two sessions of one synthetic room whose
map frames differ by a known yaw and translation (tests/runtime/test_graph_relocalize.py), stored with
their centre views through the archive writer."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from runtime.mapping.submap import Submap
from tests.runtime.test_graph_relocalize import K, _pose, _rz, _sessions
from tests.tools.test_map_archive import HEADER, make_submap
from tools.cli import main
from tools.map_archive import MapArchiveWriter, read_manifest
from tools.map_archive.reader import load_view

T_PW = _pose(_rz(-25.0), [0.4, 1.1, 0.0])
T_NW = _pose(_rz(40.0), [1.5, -2.0, 0.3])


def _write_session(folder: Path, views, with_views: bool = True, archive_views: bool = True) -> list[Submap]:
    subs = []
    for pv in views:
        sm = make_submap(pv.index, seed=100 + pv.index)
        sm.K, sm.T_MS = K.copy(), pv.T_MS
        sm.T_OS = pv.T_MS.copy()
        sm.view = (pv.features, pv.view) if with_views else None
        subs.append(sm)
    w = MapArchiveWriter(folder / "map", HEADER, views=archive_views)
    w.commit(subs, [], 1, {})
    (folder / "run_status.json").write_text('{"status": "complete"}')
    return subs


@pytest.fixture
def sessions(tmp_path: Path) -> tuple[Path, Path]:
    prior, new = _sessions(T_PW, T_NW)
    _write_session(tmp_path / "prior", prior)
    _write_session(tmp_path / "new", new)
    return tmp_path / "prior", tmp_path / "new"


def test_views_round_trip_through_the_archive(sessions):
    prior, _ = sessions
    info = read_manifest(prior / "map")
    views = _sessions(T_PW, T_NW)[0]
    for e, pv in zip(sorted(info["submaps"], key=lambda e: e["index"]), views, strict=True):
        f, v = load_view(prior / "map", e)
        assert np.array_equal(f.kpts, pv.features.kpts) and f.level is None
        assert np.allclose(f.desc, pv.features.desc, atol=1e-3)          # float16 on disk
        assert f.desc.dtype == np.float32
        assert np.allclose(v.depth_at_kpts, pv.view.depth_at_kpts, rtol=1e-6)
        assert np.array_equal(v.K, K) and v.image_size == pv.view.image_size


def test_align_puts_the_new_map_and_its_trajectory_in_the_prior_frame(sessions, capsys):
    prior, new = sessions
    t_ns = np.array([10**18, 10**18 + 50_000_000])
    p_N = np.array([[1.0, 2.0, 0.5], [1.2, 2.1, 0.6]])
    (new / "final.tum").write_text("".join(f"{t * 1e-9:.9f} {x} {y} {z} 0 0 0 1\n"
                                           for t, (x, y, z) in zip(t_ns, p_N, strict=True)))
    assert main(["map", "align", str(new), "--to", str(prior)]) == 0
    out = capsys.readouterr().out
    assert "localised" in out and "fit: centres" in out
    al = json.loads((new / "alignment.json").read_text())
    T_true = T_PW @ np.linalg.inv(T_NW)
    assert np.allclose(np.array(al["T_PN"]), T_true, atol=0.03)
    assert al["localized"] and al["agreeing_new_views"] >= 3 and al["final_prior_poses"] == 2
    moved = np.loadtxt(new / "final.prior.tum")
    assert np.allclose(moved[:, 1:4], p_N @ T_true[:3, :3].T + T_true[:3, 3], atol=0.05)
    yaw = np.arctan2(T_true[1, 0], T_true[0, 0])                    # identity attitude -> pure yaw
    assert np.allclose(np.abs(moved[:, 7]), np.cos(yaw / 2), atol=2e-3)


def test_another_place_is_not_localised_and_exits_1(tmp_path, capsys):
    prior, other = _sessions(np.eye(4), np.eye(4), new_room_seed=7)
    _write_session(tmp_path / "prior", prior)
    _write_session(tmp_path / "other", other)
    (tmp_path / "other" / "final.tum").write_text("1.0 0 0 0 0 0 0 1\n")
    assert main(["map", "align", str(tmp_path / "other"), "--to", str(tmp_path / "prior"), "--json"]) == 1
    al = json.loads(capsys.readouterr().out)
    assert not al["localized"] and al["T_PN"] is None and al["reason"]
    assert not (tmp_path / "other" / "final.prior.tum").exists()


def test_an_archive_without_views_is_refused_with_the_reason(tmp_path, capsys):
    prior, new = _sessions(T_PW, T_NW)
    _write_session(tmp_path / "prior", prior, with_views=False)
    _write_session(tmp_path / "new", new)
    assert main(["map", "align", str(tmp_path / "new"), "--to", str(tmp_path / "prior")]) != 0
    err = capsys.readouterr().err
    assert "stores no centre views" in err and "prior" in err
    assert main(["map", "align", str(tmp_path / "new"), "--to", str(tmp_path / "new")]) != 0
    assert "same map" in capsys.readouterr().err


def test_align_elsewhere_replaces_a_trajectory_there_only_with_overwrite(sessions, tmp_path, capsys):
    prior, new = sessions
    (new / "final.tum").write_text("1.0 0 0 0 0 0 0 1\n")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "final.prior.tum").write_text("mine\n")
    args = ["map", "align", str(new), "--to", str(prior), "--out", str(elsewhere / "a.json")]
    assert main(args) != 0
    assert "final.prior.tum" in capsys.readouterr().err
    assert (elsewhere / "final.prior.tum").read_text() == "mine\n" and not (elsewhere / "a.json").exists()
    assert main([*args, "--overwrite"]) == 0
    assert len(np.loadtxt(elsewhere / "final.prior.tum", ndmin=2)) == 1


def test_a_long_map_is_subsampled_evenly_and_said(sessions):
    from tools.map_archive.align import load_place_views

    prior, _ = sessions
    notes: list[str] = []
    views, segment, segments = load_place_views(prior / "map", notes, max_views=4)
    assert [v.index for v in views] == [0, 4, 7, 11] and (segment, segments) == (0, 1)
    assert views[0].features.desc.dtype == np.float16                 # kept compact in memory
    assert any("12 submaps; 4 of their views" in n for n in notes)


@pytest.mark.parametrize("T_MS", [np.eye(3).tolist(), np.zeros((4, 4)).tolist()])
def test_a_view_whose_state_is_not_rigid_is_left_out_not_a_crash(sessions, capsys, T_MS):
    """A hand-edited manifest: a 3x3 T_MS raised deep inside the relocalizer (IndexError / matmul) and an
    all-zero one raised LinAlgError."""
    from tools.map_archive.align import load_place_views

    prior, new = sessions
    path = prior / "map" / "manifest.json"
    info = json.loads(path.read_text())
    info["submaps"][3]["T_MS"] = T_MS
    path.write_text(json.dumps(info))
    notes: list[str] = []
    views, _, _ = load_place_views(prior / "map", notes)
    assert 3 not in [v.index for v in views] and len(views) == 11
    assert any("1 submap(s) whose graph state places no point" in n for n in notes)
    assert main(["map", "align", str(new), "--to", str(prior)]) == 0
    assert "1 submap(s) whose graph state places no point" in capsys.readouterr().err


def test_export_in_the_prior_frame_and_merged_with_the_prior_map(tmp_path, capsys):
    from dataclasses import replace

    from tests.tools.test_map_archive import assert_fusion_equals, brute_force_fusion
    from tools.evaluation.ply import read_ply_vertices

    prior_views, new_views = _sessions(T_PW, T_NW)
    prior_subs = _write_session(tmp_path / "prior", prior_views)
    new_subs = _write_session(tmp_path / "new", new_views)
    new = tmp_path / "new"
    assert main(["map", "export", str(new), "--in-prior"]) != 0          # not aligned yet
    assert "align the run first" in capsys.readouterr().err
    assert main(["map", "align", str(new), "--to", str(tmp_path / "prior")]) == 0
    T = np.array(json.loads((new / "alignment.json").read_text())["T_PN"])
    moved = [replace(s, T_MS=T @ s.T_MS) for s in new_subs]
    assert main(["map", "export", str(new), "--in-prior", "--voxel", "0.25"]) == 0
    pts = read_ply_vertices(new / "map.prior.ply")
    expected = brute_force_fusion(moved, 0.25)
    assert len(pts) == len(expected)
    from tools.map_archive import fuse_archive

    assert_fusion_equals(fuse_archive(new / "map", 0.25, T_out=T), expected, 0.25)
    assert main(["map", "export", str(new), "--merge-prior", "--voxel", "0.25"]) == 0
    merged = brute_force_fusion(prior_subs + moved, 0.25)
    assert len(read_ply_vertices(new / "map.merged.ply")) == len(merged)


def test_a_pair_of_runs_moved_together_still_merges(tmp_path, capsys):
    """alignment.json kept only the prior's absolute path: after both runs were copied to another disk or
    machine, --merge-prior said the prior map was gone."""
    import shutil

    from tools.evaluation.ply import read_ply_vertices

    prior_views, new_views = _sessions(T_PW, T_NW)
    _write_session(tmp_path / "a" / "prior", prior_views)
    _write_session(tmp_path / "a" / "new", new_views)
    assert main(["map", "align", str(tmp_path / "a" / "new"), "--to", str(tmp_path / "a" / "prior")]) == 0
    assert json.loads((tmp_path / "a/new/alignment.json").read_text())["prior_relative"] == "../prior/map"
    assert main(["map", "export", str(tmp_path / "a" / "new"), "--merge-prior", "--voxel", "0.25"]) == 0
    merged = len(read_ply_vertices(tmp_path / "a/new/map.merged.ply"))
    capsys.readouterr()
    shutil.move(tmp_path / "a", tmp_path / "b")                       # both runs moved together
    new = tmp_path / "b" / "new"
    (new / "map.merged.ply").unlink()
    assert main(["map", "export", str(new), "--merge-prior", "--voxel", "0.25"]) == 0
    assert f"{tmp_path / 'a/prior/map'} is gone (the runs were moved?): using " \
           f"{tmp_path / 'b/prior/map'}" in capsys.readouterr().err
    assert len(read_ply_vertices(new / "map.merged.ply")) == merged
    # a copy of the pair, and another map written where the prior was recorded: the copy's own prior is used
    shutil.copytree(tmp_path / "b", tmp_path / "c")
    _write_session(tmp_path / "a" / "prior", _sessions(T_PW, T_NW, new_room_seed=7)[0])
    assert main(["map", "export", str(tmp_path / "c" / "new"), "--merge-prior", "--voxel", "0.25",
                 "--overwrite"]) == 0
    said = f"{tmp_path / 'a/prior/map'} holds another map (replaced since): using {tmp_path / 'c/prior/map'}"
    assert said in capsys.readouterr().err
    # another map where the relative path leads: not taken (its id is not the aligned prior's)
    shutil.rmtree(tmp_path / "b" / "prior")
    _write_session(tmp_path / "b" / "prior", _sessions(T_PW, T_NW, new_room_seed=7)[0])
    assert main(["map", "export", str(new), "--merge-prior", "--voxel", "0.25", "--overwrite"]) == 1
    assert "is not the map this run was aligned to" in capsys.readouterr().err


def test_map_info_counts_the_stored_views(tmp_path, capsys):
    prior_views, _ = _sessions(T_PW, T_NW)
    _write_session(tmp_path / "with", prior_views)
    _write_session(tmp_path / "without", prior_views, with_views=False)
    assert main(["map", "info", str(tmp_path / "with"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["views"] == len(prior_views)
    assert main(["map", "info", str(tmp_path / "without")]) == 0
    assert "0 of 12 submaps keep their centre view (this map cannot be aligned" in capsys.readouterr().out


def test_an_archive_outside_a_run_folder_leaves_its_neighbours_alone(sessions, tmp_path, capsys):
    import shutil

    prior, new = sessions
    loose = tmp_path / "loose"
    shutil.copytree(new / "map", loose / "sessionB_map")
    (loose / "alignment.json").write_text('{"mine": true}\n')
    (loose / "final.tum").write_text("1.0 0 0 0 0 0 0 1\n")          # some other run's trajectory
    assert main(["map", "align", str(loose / "sessionB_map"), "--to", str(prior)]) != 0
    assert "--overwrite" in capsys.readouterr().err and json.loads((loose / "alignment.json").read_text())
    assert main(["map", "align", str(loose / "sessionB_map"), "--to", str(prior),
                 "--out", str(tmp_path / "b.json")]) == 0
    assert "final_prior" not in json.loads((tmp_path / "b.json").read_text())
    assert not (tmp_path / "final.prior.tum").exists() and not (loose / "final.prior.tum").exists()


def test_a_run_configured_not_to_archive_views_writes_none(tmp_path):
    prior_views, _ = _sessions(T_PW, T_NW)
    _write_session(tmp_path / "r", prior_views, archive_views=False)     # mapping.archive_views = false
    info = read_manifest(tmp_path / "r" / "map")
    assert all(load_view(tmp_path / "r" / "map", e) is None for e in info["submaps"])


def _two_segment_session(folder: Path) -> list[Submap]:
    """The new session's views, its first submap in filter segment 0 and the rest in segment 1."""
    _, new_views = _sessions(T_PW, T_NW)
    subs = []
    for pv in new_views:
        sm = make_submap(pv.index, seed=100 + pv.index)
        sm.K, sm.T_MS, sm.T_OS, sm.view = K.copy(), pv.T_MS, pv.T_MS.copy(), (pv.features, pv.view)
        sm.segment = 0 if pv.index == 0 else 1
        subs.append(sm)
    MapArchiveWriter(folder / "map", HEADER).commit(subs, [], 1, {})
    (folder / "run_status.json").write_text('{"status": "complete"}')
    (folder / "final.tum").write_text("1.0 0 0 0 0 0 0 1\n")
    return subs


@pytest.mark.parametrize("last_segment, moved", [(1, True), (2, False)])
def test_final_tum_is_moved_only_when_it_holds_the_aligned_segment(sessions, tmp_path, capsys, last_segment,
                                                                   moved):
    prior, _ = sessions
    run = tmp_path / "two"
    _two_segment_session(run)
    (run / "poses.csv").write_text(f"t_ns,t_cam_ns,segment,source,correction_version,interpolation_fraction\n"
                                   f"1000000000,1000000000,{last_segment},native:static,0,1.000000\n")
    assert main(["map", "align", str(run), "--to", str(prior)]) == 0
    al = json.loads((run / "alignment.json").read_text())
    assert al["new_segment"] == 1 and al["new_segments"] == 2
    assert (run / "final.prior.tum").exists() is moved
    if not moved:
        assert "final.tum not moved" in capsys.readouterr().err
    # the map in the prior frame holds only the aligned segment's submaps, and says so
    assert main(["map", "export", str(run), "--in-prior", "--voxel", "0.25"]) == 0
    assert "1 submap(s) of other filter segments left out" in capsys.readouterr().err


def test_a_live_runs_alignment_is_replaced_only_with_overwrite_and_a_stale_trajectory_after_the_write(
        sessions, tmp_path, capsys):
    from tools.run_prior_frame import LIVE_ALIGNMENT

    prior, new = sessions
    (new / "final.tum").write_text("1.0 0 0 0 0 0 0 1\n")
    (new / "alignment.json").write_text(json.dumps({"new": LIVE_ALIGNMENT, "localized": True,
                                                    "prior": "/elsewhere/runX/map"}))
    (new / "causal.prior.tum").write_text("1.0 0 0 0 0 0 0 1\n")     # published in runX's frame
    assert main(["map", "align", str(new), "--to", str(prior)]) != 0
    assert "--overwrite" in capsys.readouterr().err
    assert json.loads((new / "alignment.json").read_text())["new"] == LIVE_ALIGNMENT
    assert (new / "causal.prior.tum").exists()
    assert main(["map", "align", str(new), "--to", str(prior), "--overwrite"]) == 0
    assert (new / "final.prior.tum").exists()
    # the live poses were in another prior's frame: the file no longer matches alignment.json; kept aside
    assert not (new / "causal.prior.tum").exists()
    assert (new / "causal.earlier-prior.tum").read_text() == "1.0 0 0 0 0 0 0 1\n"
    assert ("causal.prior.tum renamed to causal.earlier-prior.tum: it holds the poses published in the frame "
            "of /elsewhere/runX/map") in capsys.readouterr().err
    # an own earlier result whose new alignment moves nothing: the stale trajectory goes, after the write
    _, other = _sessions(np.eye(4), np.eye(4), new_room_seed=7)        # another room
    _write_session(tmp_path / "elsewhere", other)
    assert main(["map", "align", str(new), "--to", str(tmp_path / "elsewhere")]) == 1
    assert not (new / "final.prior.tum").exists()
    assert not json.loads((new / "alignment.json").read_text())["localized"]


def test_a_prior_maps_id_is_taken_when_it_is_loaded(sessions) -> None:
    """The live alignment recorded the id read when the run ended: a prior replaced during the run gave the
    replacement's id, which export then accepted."""
    import shutil

    from tools.map_archive.align import prior_map_localizer

    prior, new = sessions
    loaded = json.loads((prior / "map" / "manifest.json").read_text())["archive_id"]
    loc = prior_map_localizer(prior, [])
    shutil.rmtree(prior / "map")
    shutil.copytree(new / "map", prior / "map")      # replaced while the run goes on
    assert loc.prior_id == loaded != json.loads((prior / "map" / "manifest.json").read_text())["archive_id"]


def test_after_a_reset_the_aligned_segments_own_final_trajectory_is_moved(sessions, tmp_path, capsys) -> None:
    """final.tum holds the last segment; when another was aligned, its final_segment<K>.tum (written after a
    reset) is what final.prior.tum must hold, not nothing."""
    from tools.evaluation import read_tum

    prior, _ = sessions
    run = tmp_path / "two"
    _two_segment_session(run)
    (run / "poses.csv").write_text("t_ns,t_cam_ns,segment,source,correction_version,interpolation_fraction\n"
                                   "1000000000,1000000000,2,native:static,0,1.000000\n")
    (run / "final_segment1.tum").write_text("2.0 1 2 3 0 0 0 1\n")
    assert main(["map", "align", str(run), "--to", str(prior)]) == 0
    assert "final.prior.tum holds filter segment 1 (final_segment1.tum), the one aligned; final.tum holds " \
           "the last (2)" in capsys.readouterr().err
    al = json.loads((run / "alignment.json").read_text())
    assert al["final_prior_source"] == "final_segment1.tum" and al["final_prior_poses"] == 1
    T = np.array(al["T_PN"])
    moved = read_tum(run / "final.prior.tum")
    np.testing.assert_allclose(moved.p[0], T[:3, :3] @ [1.0, 2.0, 3.0] + T[:3, 3], atol=1e-6)
