"""`davio eval` and `davio map` on bad input: one-line errors (exit 1), nanosecond TUM stamps, output
paths that are folders, strict JSON."""
from __future__ import annotations

import json
import os
import stat
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import cli_exit
from tests.tools.test_eval_io import random_traj
from tests.tools.test_map_archive import write_two_commits
from tools.cli import main
from tools.evaluation import write_tum


def _strict(text: str) -> dict:
    return json.loads(text, parse_constant=lambda c: pytest.fail(f"non-strict JSON token {c}"))


@pytest.fixture()
def tum_pair(tmp_path: Path) -> tuple[Path, Path, Path]:
    """(estimate with seconds stamps, the same estimate with nanosecond stamps, reference)."""
    traj = random_traj(40)
    write_tum(tmp_path / "est.tum", traj)
    write_tum(tmp_path / "ref.tum", traj)
    rows = [line.split() for line in (tmp_path / "est.tum").read_text().splitlines()[1:]]
    (tmp_path / "est_ns.tum").write_text("".join(" ".join([r[0].replace(".", "").lstrip("0")] + r[1:]) + "\n"
                                                 for r in rows))
    return tmp_path / "est.tum", tmp_path / "est_ns.tum", tmp_path / "ref.tum"


@pytest.mark.parametrize("metric", ["ate", "rpe"])
def test_nanosecond_tum_stamps_are_read_with_a_note(tum_pair, capsys, metric: str) -> None:
    est, est_ns, ref = tum_pair
    assert main(["eval", metric, str(est), str(ref), "--json"]) == 0
    expected = _strict(capsys.readouterr().out)
    assert main(["eval", metric, str(est_ns), str(ref), "--json"]) == 0
    captured = capsys.readouterr()
    got = _strict(captured.out)
    assert got["pairs"] == expected["pairs"] >= 39 and got["rmse"] == expected["rmse"]
    assert "davio eval: note:" in captured.err and "read as nanoseconds" in captured.err
    assert main(["eval", metric, str(est_ns), str(ref)]) == 0  # the table too
    assert "read as nanoseconds" in capsys.readouterr().err


@pytest.mark.parametrize("metric", ["ate", "rpe"])
def test_repeated_stamps_are_counted_and_said(tum_pair, tmp_path: Path, capsys, metric: str) -> None:
    """A repeated stamp is kept (as evo keeps it) but never silently: each file's count is said on stderr
    and given in the JSON (the pair count and the statistics depend on which twin is paired)."""
    est, _, ref = tum_pair
    rows = est.read_text().splitlines()
    header, body = rows[0], rows[1:]
    repeated = [body[5].split(), body[20].split()]
    for r in repeated:
        r[1] = str(float(r[1]) + 0.5)            # the twin is another pose at the same stamp
    body = body[:6] + [" ".join(repeated[0])] + body[6:21] + [" ".join(repeated[1])] + body[21:]
    est_rep = tmp_path / "est_repeated.tum"
    est_rep.write_text("\n".join([header, *body]) + "\n")
    ref_rows = ref.read_text().splitlines()
    ref_rep = tmp_path / "ref_repeated.tum"
    ref_rep.write_text("\n".join(ref_rows[:4] + ref_rows[3:]) + "\n")
    assert main(["eval", metric, str(est_rep), str(ref_rep), "--json"]) == 0
    captured = capsys.readouterr()
    assert _strict(captured.out)["repeated_stamps"] == {"est": 2, "ref": 1}
    assert f"davio eval: note: {est_rep}: 2 poses repeat the stamp before (kept" in captured.err
    assert f"davio eval: note: {ref_rep}: 1 pose repeats the stamp before (kept" in captured.err
    assert main(["eval", metric, str(est), str(ref), "--json"]) == 0
    captured = capsys.readouterr()
    assert _strict(captured.out)["repeated_stamps"] == {"est": 0, "ref": 0} and "repeat" not in captured.err


def test_save_aligned_into_an_existing_folder(tum_pair, tmp_path: Path, capsys) -> None:
    est, _, ref = tum_pair
    out = tmp_path / "results"
    out.mkdir()
    assert main(["eval", "ate", str(est), str(ref), "--save-aligned", str(out), "--json"]) == 0
    result = _strict(capsys.readouterr().out)
    assert result["aligned"] == str(out / "est_aligned.tum")
    assert len((out / "est_aligned.tum").read_text().splitlines()) == 41  # header + 40 poses
    assert main(["eval", "ate", str(est), str(ref), "--save-aligned", str(out)]) == 1   # exists now
    target = out / "est_aligned.tum"
    assert capsys.readouterr().err == (f"davio eval ate: error: --save-aligned {target}: exists; "
                                       "pass --overwrite to replace it, or choose another file\n")
    assert main(["eval", "ate", str(est), str(ref), "--save-aligned", str(out), "--overwrite"]) == 0
    assert "aligned estimate" in capsys.readouterr().out  # the table row (rich may shorten the path)


def test_save_aligned_never_replaces_an_input_or_a_device(tum_pair, tmp_path: Path, capsys) -> None:
    est, _, ref = tum_pair
    before = ref.read_bytes()
    for target, why in [(ref, "is one of this command's inputs"),
                        (tmp_path / "aligned", "expected a .tum or .txt file"),
                        (tmp_path / "no" / "such" / "a.tum", "does not exist")]:
        assert main(["eval", "ate", str(est), str(ref), "--save-aligned", str(target), "--overwrite"]) == 1
        assert why in capsys.readouterr().err
    assert ref.read_bytes() == before and not (tmp_path / "aligned").exists()
    fifo = tmp_path / "pipe.tum"
    os.mkfifo(fifo)
    assert main(["eval", "ate", str(est), str(ref), "--save-aligned", str(fifo), "--overwrite"]) == 1
    assert "is not a regular file" in capsys.readouterr().err
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)


@pytest.mark.parametrize("metric", ["ate", "rpe"])
def test_plot_naming_a_file_is_a_one_line_error(tum_pair, capsys, metric: str) -> None:
    est, _, ref = tum_pair
    assert main(["eval", metric, str(est), str(ref), "--plot", str(ref)]) == 1
    err = capsys.readouterr().err
    assert err == (f"davio eval {metric}: error: --plot {ref}: is a file; --plot takes a folder for the PNG "
                   "plots\n")


@pytest.mark.parametrize("metric", ["ate", "rpe"])
def test_the_plot_folder_is_made_only_when_plots_are_written(tum_pair, tmp_path, capsys, metric: str) -> None:
    est, _, ref = tum_pair
    plots = tmp_path / "new" / "plots"
    empty = tmp_path / "empty.tum"
    empty.write_text("")
    assert main(["eval", metric, str(empty), str(ref), "--plot", str(plots)]) == 1   # fails: no folder left
    capsys.readouterr()
    assert not (tmp_path / "new").exists()
    assert main(["eval", metric, str(est), str(ref), "--plot", str(plots), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["plots"] and all(Path(p).is_file() and Path(p).parent == plots for p in out["plots"])


@pytest.mark.parametrize("argv, code, message", [
    (["--offset", "nan"], 2, "argument --offset: 'nan' is not a finite number"),
    (["--offset", "1e300"], 1, "--offset must be a finite number"),
    (["--max-diff", "nan"], 2, "argument --max-diff: 'nan' is not a finite number"),
    (["--max-diff", "-1"], 1, "--max-diff must be a finite number in [0, 9.2e+09], got -1.0"),
    (["--n-align", "-3"], 2, "argument --n-align: must be >= 2, got -3"),
    (["--n-align", "1"], 2, "argument --n-align: must be >= 2, got 1"),
    (["--plot", "/proc/davio-plots"], 1, "--plot /proc/davio-plots: cannot create the folder"),
])
def test_bad_numbers_and_unwritable_plot_folders_are_named_before_any_work(tum_pair, capsys, argv, code,
                                                                          message) -> None:
    est, _, ref = tum_pair
    assert cli_exit(["eval", "ate", str(est), str(ref), *argv]) == code
    assert message in capsys.readouterr().err


def test_an_epoch_offset_and_exact_stamps_are_accepted(tum_pair, capsys) -> None:
    """--offset of an epoch (estimate stamped from 0, reference in epoch seconds) and --max-diff 0 (exact
    stamps only) are legitimate: they pass the checks (the evaluation then says what it found)."""
    import argparse

    from tools.commands.eval import check_numbers

    check_numbers(argparse.Namespace(offset=1403636579.8, max_diff=0.0, n_align=None))


def test_surface_voxel_and_threshold_must_be_positive_numbers(tmp_path: Path, capsys) -> None:
    cloud = tmp_path / "c.npy"
    np.save(cloud, np.random.default_rng(0).uniform(0, 1, (50, 3)))
    for flag, value, must in (("--voxel", "1e-6", "in [0.0001, 100]"),
                              ("--threshold", "0", "in [1e-06, 100]"),
                              ("--threshold", "-1", "in [1e-06, 100]")):
        assert main(["eval", "surface", str(cloud), str(cloud), flag, value]) == 1
        assert f"{flag} must be a finite number {must}" in capsys.readouterr().err
    for flag in ("--voxel", "--threshold"):
        assert cli_exit(["eval", "surface", str(cloud), str(cloud), flag, "inf"]) == 2
        assert f"argument {flag}: 'inf' is not a finite number" in capsys.readouterr().err


def test_surface_counts_the_points_it_leaves_out(tmp_path: Path, capsys) -> None:
    pts = np.random.default_rng(0).uniform(0, 1, (2001, 3))
    pts[7] = np.nan
    rec = tmp_path / "rec.npy"
    np.save(rec, pts)
    assert main(["eval", "surface", str(rec), str(rec), "--json"]) == 0
    out = capsys.readouterr()
    assert f"{rec}: 1 of 2001 points are not finite (NaN or Inf) and are left out" in out.err
    res = json.loads(out.out)
    assert res["nonfinite_points"] == {"rec": 1, "ref": 1} and res["n_rec"] == 2000


def test_surface_refuses_a_trajectory_of_another_segment_than_map_ply(tmp_path: Path, capsys) -> None:
    """After a reset map.ply holds the segment with the most placeable submaps, final.tum the last one: the
    README's `--align-with final.tum` moved map.ply by an unrelated frame's alignment and scored it."""
    run = tmp_path / "run"
    run.mkdir()
    cloud = np.random.default_rng(0).uniform(0, 4, (300, 3))
    from tools.map_archive.export import write_ply

    write_ply(run / "map.ply", cloud, np.full(len(cloud), 128, np.uint8), ("segment 0",))
    traj = random_traj(40)
    for name in ("final.tum", "final_segment0.tum", "final_segment1.tum"):
        write_tum(run / name, traj)
    write_tum(tmp_path / "gt.tum", traj)
    (run / "report.json").write_text(json.dumps({"map": {"ply": "map.ply", "ply_segment": 0},
                                                 "segments": [{"poses": 40}, {"poses": 5}]}))
    argv = ["eval", "surface", str(run / "map.ply"), str(run / "map.ply"), "--json", "--align-with"]
    for est in ("final.tum", "final_segment1.tum"):
        assert main(argv + [str(run / est), str(tmp_path / "gt.tum")]) == 1
        err = capsys.readouterr().err
        assert "holds filter segment 0 of the run" in err
        assert f"align with {run / 'final_segment0.tum'}" in err
    assert main(argv + [str(run / "final_segment0.tum"), str(tmp_path / "gt.tum")]) == 0
    assert _strict(capsys.readouterr().out)["fscore"] == 1.0
    # map.ply re-exported with `davio map export RUN --segment 1`: the PLY says which segment it holds
    write_ply(run / "map.ply", cloud, np.full(len(cloud), 128, np.uint8), ("segment 1",))
    for est in ("final.tum", "final_segment1.tum"):
        assert main(argv + [str(run / est), str(tmp_path / "gt.tum")]) == 0
    assert main(argv + [str(run / "final_segment0.tum"), str(tmp_path / "gt.tum")]) == 1
    # a map.ply of an older davio (no comment), as its run wrote it: report.json's ply_segment says
    write_ply(run / "map.ply", cloud, np.full(len(cloud), 128, np.uint8))
    (run / "report.json").write_text(json.dumps({"map": {"ply": "map.ply", "ply_segment": 0},
                                                 "segments": [{"poses": 40}, {"poses": 5}]}))
    assert main(argv + [str(run / "final.tum"), str(tmp_path / "gt.tum")]) == 1
    assert "holds filter segment 0 of the run" in capsys.readouterr().err
    (run / "report.json").write_text(json.dumps({"map": {"ply": "map.ply", "ply_segment": 0},
                                                 "segments": [{"poses": 40}]}))     # no reset: as before
    assert main(argv + [str(run / "final_segment0.tum"), str(tmp_path / "gt.tum")]) == 0


def test_simulate_into_a_folder_that_cannot_be_made_fails_before_rendering(capsys) -> None:
    assert main(["simulate", "--seconds", "1", "--out", "/proc/davio-sim"]) == 1
    err = capsys.readouterr().err
    assert "--out /proc/davio-sim" in err and "building scene" not in err


@pytest.mark.parametrize(
    "body,message",
    [
        (b"", "PLY file ends at end_header: the header declares 3 vertices but no vertex data follows "
              "(truncated file)"),
        (b"\n0 0 0\n", "PLY body holds 1 vertex rows, header says 3 (truncated file)"),
    ],
)
def test_surface_on_a_truncated_ply_is_a_one_line_error(tmp_path: Path, capsys, body: bytes,
                                                        message: str) -> None:
    rec = tmp_path / "rec.ply"
    rec.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                    b"property float z\nend_header" + body)
    np.save(tmp_path / "ref.npy", np.eye(3))
    assert main(["eval", "surface", str(rec), str(tmp_path / "ref.npy")]) == 1
    assert capsys.readouterr().err == f"davio eval surface: error: {rec}: {message}\n"


def test_surface_json_is_strict_and_a_folder_is_refused(tmp_path: Path, capsys) -> None:
    np.save(tmp_path / "a.npy", np.eye(3))
    assert main(["eval", "surface", str(tmp_path / "a.npy"), str(tmp_path / "a.npy"), "--json"]) == 0
    assert _strict(capsys.readouterr().out)["fscore"] == 1.0
    assert main(["eval", "surface", str(tmp_path), str(tmp_path / "a.npy")]) == 1
    assert capsys.readouterr().err == (f"davio eval surface: error: {tmp_path}: is a folder, not a point "
                                       "cloud file\n")
    np.save(tmp_path / "s.npy", np.array([["a", "b", "c"]]))
    assert main(["eval", "surface", str(tmp_path / "s.npy"), str(tmp_path / "a.npy")]) == 1
    assert "not a numeric numpy array file" in capsys.readouterr().err


def test_map_export_into_a_folder_and_bad_voxel(tmp_path: Path, capsys) -> None:
    write_two_commits(tmp_path / "run" / "map")
    out = tmp_path / "exports"
    out.mkdir()
    assert main(["map", "export", str(tmp_path / "run"), "--out", str(out)]) == 0
    assert (out / "map.ply").is_file()
    capsys.readouterr()
    assert main(["map", "export", str(tmp_path / "run"), "--voxel", "0"]) == 1
    assert capsys.readouterr().err == ("davio map export: error: --voxel must be an edge length from 0.005 "
                                       "to 10.0 m, got 0.0\n")
    assert main(["map", "export", str(tmp_path / "run"), "--voxel", "1e-6"]) == 1
    assert "--voxel must be an edge length" in capsys.readouterr().err
    for bad in ("inf", "nan"):
        assert cli_exit(["map", "export", str(tmp_path / "run"), "--voxel", bad]) == 2
        assert "is not a finite number" in capsys.readouterr().err
    assert main(["map", "info", str(tmp_path / "run"), "--json"]) == 0
    assert _strict(capsys.readouterr().out)["submaps"] == 3


def test_manifest_entry_with_a_foreign_file_name_is_refused(tmp_path: Path, capsys) -> None:
    folder = tmp_path / "map"
    write_two_commits(folder)
    manifest = json.loads((folder / "manifest.json").read_text())
    manifest["submaps"][1]["file"] = "../../etc/passwd"
    (folder / "manifest.json").write_text(json.dumps(manifest))
    assert main(["map", "info", str(folder)]) == 1
    assert "submaps[1].file is '../../etc/passwd', expected a name like submap_000000.npz" in \
        capsys.readouterr().err


def test_n_align_beyond_the_pairs_is_said_and_recorded(tum_pair, capsys) -> None:
    est, _, ref = tum_pair
    assert main(["eval", "ate", str(est), str(ref), "--n-align", "100000", "--json"]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["n_align"] == 40              # was silently all of them
    assert "--n-align 100000 exceeds the 40 associated pairs" in captured.err
    assert main(["eval", "ate", str(est), str(ref), "--n-align", "10", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["n_align"] == 10


def test_a_surface_threshold_beyond_100_m_is_refused(tmp_path: Path, capsys) -> None:
    cloud = tmp_path / "c.npy"
    np.save(cloud, np.random.default_rng(0).uniform(0, 1, (50, 3)))
    assert main(["eval", "surface", str(cloud), str(cloud), "--threshold", "1e308"]) == 1    # F = 1.0
    assert "--threshold must be a finite number in" in capsys.readouterr().err
