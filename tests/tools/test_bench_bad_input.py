"""Benchmark and evaluation inputs found by fuzzing their options: the result file is checked before the
run, a run's own files and maps are never replaced, and errors go to stderr in one line."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tools.cli import main


def test_a_result_file_is_checked_before_the_run(tmp_path: Path, capsys, monkeypatch) -> None:
    import tools.benchmarks.graph_solve as graph_solve

    def no_run(*a, **k):
        raise AssertionError("the benchmark ran before --out was checked")

    monkeypatch.setattr(graph_solve, "measure", no_run)
    argv = ["bench", "graph-solve", "--sizes", "8", "--repeats", "1", "--out"]
    assert main([*argv, str(tmp_path / "nowhere" / "r.json")]) == 1       # the run's result was lost
    assert "folder" in capsys.readouterr().err
    inputs = tmp_path / "sim_info.txt"             # one of a benchmark's own inputs, say
    inputs.write_text("cam0 w 752 h 480\n")
    assert main([*argv, str(inputs)]) == 1
    assert "exists and is not a JSON result" in capsys.readouterr().err
    assert inputs.read_text() == "cam0 w 752 h 480\n"
    monkeypatch.undo()
    earlier = tmp_path / "r.json"
    earlier.write_text('{"an": "earlier result"}')
    assert main([*argv, str(earlier)]) == 0                                  # re-running replaces it
    assert json.loads(earlier.read_text())["benchmark"] == "graph-solve"


def test_map_export_never_replaces_a_map_it_did_not_write(tmp_path: Path, capsys) -> None:
    run = tmp_path / "run1"
    (run / "map").mkdir(parents=True)
    manifest = '{"model": {"description": "da3-base"}, "submaps": []}'
    (run / "map" / "manifest.json").write_text(manifest)
    argv = ["bench", "map-export", "--submaps", "2", "--anchor-max", "2", "--max-depth", "3", "--dir"]
    assert main([*argv, str(run)]) == 1
    assert "which this benchmark did not write" in capsys.readouterr().err
    assert (run / "map" / "manifest.json").read_text() == manifest
    assert main([*argv, str(tmp_path / "bench")]) == 0 and main([*argv, str(tmp_path / "bench")]) == 0


def test_bench_errors_are_one_line_on_stderr(tmp_path: Path, capsys) -> None:
    assert main(["bench", "openvins-sim", str(tmp_path / "absent"), "--json"]) == 1
    captured = capsys.readouterr()
    assert captured.out == "" and "absent: no such folder (an openvins_sim run folder" in captured.err
    assert main(["bench", "reliability", "--only", "zzzz"]) == 1           # "0/0 as expected", exit 0
    assert "--only 'zzzz' names no probe" in capsys.readouterr().err


@pytest.mark.parametrize("name, make, said", [
    ("c6.npy", lambda p: np.save(p, np.ones((10, 6))), "holds 6 values per point, expected 3"),
    ("c.txt", lambda p: p.write_text("1 2 3\n"), "unsupported point cloud format '.txt'"),
    ("link.ply", lambda p: p.symlink_to("absent.ply"), "is a broken symbolic link"),
])
def test_surface_says_what_is_wrong_with_a_cloud(tmp_path: Path, capsys, name: str, make, said: str) -> None:
    good = tmp_path / "good.npy"
    np.save(good, np.random.default_rng(0).uniform(0, 1, (50, 3)))
    make(tmp_path / name)
    assert main(["eval", "surface", str(tmp_path / name), str(good)]) == 1      # was "no points could be
    assert said in capsys.readouterr().err                                    # read" or "does not exist"


def test_simulate_refuses_camera_stamps_without_a_real_imu(tmp_path: Path, capsys) -> None:
    assert main(["simulate", "--camera-stamps", str(tmp_path / "x.txt"), "--out", str(tmp_path / "o")]) == 1
    assert "--camera-stamps applies with --imu" in capsys.readouterr().err and not (tmp_path / "o").exists()


def test_result_file_is_a_file_and_an_empty_one_may_be_replaced(tmp_path: Path, capsys) -> None:
    argv = ["bench", "graph-solve", "--sizes", "8", "--repeats", "1", "--out"]
    assert main([*argv, str(tmp_path)]) == 1
    assert "is a folder; name the .json file to write" in capsys.readouterr().err
    empty = tmp_path / "made_by_mktemp.json"
    empty.touch()
    assert main([*argv, str(empty)]) == 0 and json.loads(empty.read_text())["benchmark"] == "graph-solve"


def test_bench_option_errors_name_the_options_given(tmp_path: Path, capsys) -> None:
    assert main(["bench", "matcher", "--source", "sim", "--gap", "100", "--pairs", "600"]) == 1
    assert "--pairs 600 x --gap 100 frames needs a 15025 s simulated recording" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["bench", "online-calib", str(tmp_path), "--focal-pct", "60"])
    assert "must be >= 0 and <= 50 %, got 60" in capsys.readouterr().err
    assert main(["bench", "calibrate", str(tmp_path), "--sources", "zz", "--json"]) == 1
    captured = capsys.readouterr()
    assert captured.out == "" and "--sources must hold" in captured.err


def test_sequence_and_keep_folders_are_named(tmp_path: Path, capsys) -> None:
    assert main(["bench", "trajectory", "--sequence", str(tmp_path / "absent")]) == 1
    assert "absent: no such folder (a euroc_imu_gt sequence" in capsys.readouterr().err   # "no groundtruth"
    (tmp_path / "k.txt").write_text("x")
    assert main(["bench", "reliability", "--only", "binary", "--keep", str(tmp_path / "k.txt")]) == 1
    assert "is a file, not a folder" in capsys.readouterr().err
    (tmp_path / "kept" / "probe00").mkdir(parents=True)
    assert main(["bench", "reliability", "--only", "binary", "--keep", str(tmp_path / "kept")]) == 1
    assert "holds the probe folders of an earlier run (probe00" in capsys.readouterr().err   # "File exists"
