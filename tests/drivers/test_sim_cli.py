"""`davio simulate` and the simulator benchmarks through the CLI."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from drivers.euroc import EurocDriver
from tests.conftest import cli_exit, shared_path
from tools.cli import main


@pytest.mark.slow
def test_simulate_writes_a_euroc_folder(tmp_path, capsys) -> None:
    out = tmp_path / "sim"
    assert main(["simulate", "--seconds", "0.6", "--exact", "--seed", "3", "--out", str(out)]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["simulation"]["preset"] == "euroc" and manifest["config"]["seed"] == 3
    n = manifest["counts"]["frames"]
    # 20 Hz from 25 ms to 0.6 s (exact mode: no exposure margin)
    assert n == len(list((out / "mav0" / "cam0" / "data").glob("*.png"))) == 12
    assert n == len(list((out / "mav0" / "depth0" / "data").glob("*.png")))
    with EurocDriver(out) as drv:
        t, gyro, accel = drv.imu_arrays()
        assert t.size == manifest["counts"]["imu_samples"] == 121
        # exact mode, at rest on the ground (EuRoC preset's static start): gravity along body x
        np.testing.assert_allclose(accel, np.tile([9.81, 0.0, 0.0], (t.size, 1)), atol=1e-9)
        np.testing.assert_allclose(gyro, 0.0, atol=1e-12)
    img = cv2.imread(str(next((out / "mav0" / "cam0" / "data").glob("*.png"))), cv2.IMREAD_UNCHANGED)
    assert img.shape == (480, 752) and img.dtype == np.uint8 and img.std() > 10


def test_simulate_refuses_a_non_empty_out_before_building_the_scene(tmp_path, capsys, monkeypatch) -> None:
    import drivers.sim.recording as recording

    def no_build(*a, **k):
        raise AssertionError("the scene was built before --out was checked")

    monkeypatch.setattr(recording.SimRecording, "from_preset", no_build)
    (tmp_path / "o").mkdir()
    (tmp_path / "o" / "notes.txt").write_text("x")
    assert main(["simulate", "--out", str(tmp_path / "o")]) == 1
    assert "is not empty" in capsys.readouterr().err
    assert main(["simulate", "--seconds", "0", "--out", str(tmp_path / "p")]) == 1
    assert "--seconds must be a finite number > 0" in capsys.readouterr().err
    (tmp_path / "finder").mkdir()
    (tmp_path / "finder" / ".DS_Store").write_text("x")   # only OS metadata: as good as empty
    with pytest.raises(AssertionError, match="the scene was built"):
        main(["simulate", "--out", str(tmp_path / "finder")])
    for cmd in (["simulate", "--out", str(tmp_path / "q")], ["demo", "--out", str(tmp_path / "d")]):
        assert main([*cmd, "--seconds", "1e9"]) == 1       # refused before anything is built
        assert "at most 14400 (4 h)" in capsys.readouterr().err
    assert cli_exit(["demo", "--seed", "-1", "--out", str(tmp_path / "d")]) == 2
    captured = capsys.readouterr()
    assert "argument --seed: must be >= 0, got -1" in captured.err and "simulating" not in captured.out
    assert not (tmp_path / "d").exists()


def test_demo_reproduce_commands_keep_every_digit() -> None:
    import argparse

    from tools.commands.demo import _reproduce

    args = argparse.Namespace(preset="euroc", seconds=3.0499999, seed=2, native_only=True, da3="base",
                              model_latency=0.25, no_map=False)
    sim, run = _reproduce(args)
    assert "--seconds 3.0499999 " in sim and "--model-latency 0.25 " in run


def test_simulate_json_prints_only_the_manifest(tmp_path, capsys) -> None:
    out = tmp_path / "sim"
    assert main(["simulate", "--seconds", "0.3", "--exact", "--no-depth", "--json", "--out", str(out)]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed == json.loads((out / "manifest.json").read_text())


def test_simulate_records_the_imu_model_and_refuses_it_where_it_cannot_apply(tmp_path, capsys) -> None:
    out = tmp_path / "sim"
    assert main(["simulate", "--seconds", "0.3", "--no-depth", "--json", "--imu-model", "euroc-measured",
                 "--out", str(out)]) == 0
    assert json.loads(capsys.readouterr().out)["config"]["imu_profile"] == "euroc-measured"
    assert main(["simulate", "--exact", "--imu-model", "euroc-measured", "--out", str(tmp_path / "a")]) == 1
    assert "cannot be combined with --imu-model" in capsys.readouterr().err
    assert main(["simulate", "--trajectory", str(tmp_path), "--imu-model", "euroc-measured",
                 "--out", str(tmp_path / "b")]) == 1
    assert "replays the real one" in capsys.readouterr().err


def test_simulate_rejects_imu_without_trajectory(tmp_path, capsys) -> None:
    assert main(["simulate", "--imu", "x.csv", "--out", str(tmp_path / "o")]) == 1
    assert "--imu needs --trajectory" in capsys.readouterr().err


@pytest.mark.parametrize("argv, said", [
    (["--start", "nan", "--trajectory", "t.tum"], "argument --start: 'nan' is not a finite number"),
    (["--start", "1e308", "--trajectory", "t.tum"], "--start must be a number of seconds from 0"),
    (["--start", "-2", "--trajectory", "t.tum"], "--start must be a number of seconds from 0"),
    (["--start", "5"], "--start applies to --trajectory"),          # was ignored without a word
    (["--motion-blur", "100000"], "must be from 1 to 64 renders per frame"),   # rendered for hours
    (["--motion-blur", "0"], "argument --motion-blur: must be >= 1, got 0"),
])
def test_simulate_start_and_motion_blur_are_checked_first(tmp_path, capsys, argv: list[str],
                                                          said: str) -> None:
    assert cli_exit(["simulate", *argv, "--out", str(tmp_path / "o")]) == (2 if "argument" in said else 1)
    assert said in capsys.readouterr().err and not (tmp_path / "o").exists()


def test_simulate_refuses_groundtruth_mode_without_a_real_imu(tmp_path, capsys) -> None:
    assert main(["simulate", "--groundtruth", "as-recorded", "--out", str(tmp_path / "o")]) == 1
    assert "--groundtruth applies to EuRoC-trajectory mode" in capsys.readouterr().err


@pytest.mark.slow
def test_simulate_euroc_trajectory_mode_from_a_folder(tmp_path) -> None:
    folder = shared_path("euroc_imu_gt", "MH_03_medium")
    out = tmp_path / "mh03"
    assert (
        main(
            ["simulate", "--trajectory", str(folder), "--seconds", "0.5", "--start", "20", "--out", str(out)]
        )
        == 0
    )
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["simulation"]["mode"] == "euroc-trajectory"
    assert manifest["config"]["groundtruth_mode"] == "imu-consistent"
    assert any("biases unknown" in note for note in manifest["notes"])  # TUM ground truth has no biases
    with EurocDriver(out) as drv:
        gt = drv.groundtruth()
        assert gt is not None and len(gt) > 90


def test_imu_drift_benchmark_json(capsys) -> None:
    shared_path("euroc_imu_gt", "V1_02_medium")
    args = ["bench", "imu-drift", "--sequence", "V1_02_medium", "--step", "20", "--json"]
    assert main(args) == 0
    res = json.loads(capsys.readouterr().out)["V1_02_medium"]
    assert res["with_gt_bias"]["windows"] >= 3
    assert res["with_gt_bias"]["position_m"]["median"] < res["zero_bias"]["position_m"]["median"]


def test_imu_drift_curve_beside_synthetic_imus(capsys) -> None:
    shared_path("euroc_imu_gt", "V1_02_medium")
    args = ["bench", "imu-drift", "--sequence", "V1_02_medium", "--step", "10", "--curve", "0.5,2",
            "--synthetic", "datasheet,euroc-measured", "--json"]
    assert main(args) == 0
    curve = json.loads(capsys.readouterr().out)["V1_02_medium"]["curve"]
    assert set(curve) == {"real", "real, imu-consistent truth", "datasheet", "euroc-measured"}
    med = {k: [c["position_m"]["median"] for c in v.values()] for k, v in curve.items()}
    assert all(m[1] > m[0] for m in med.values())   # drift grows with the window
    # the datasheet densities drift far less than the real IMU; the measured model about as much
    assert med["datasheet"][1] < 0.6 * med["real"][1] < med["euroc-measured"][1] < 1.6 * med["real"][1]
    assert main(["bench", "imu-drift", "--synthetic", "datasheet"]) == 1
    assert "--synthetic needs --curve" in capsys.readouterr().err


@pytest.mark.slow
def test_renderer_benchmark_json(capsys) -> None:
    assert main(["bench", "renderer", "--frames", "3", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert (res["width"], res["height"]) == (752, 480)
    assert res["frame_ms"] > 0 and res["depth_valid_fraction"] == 1.0


def test_workqueue_layer_is_preferred_unless_the_user_chose_one(monkeypatch) -> None:
    import numba

    from drivers.sim.threads import prefer_workqueue_layer

    monkeypatch.setattr(numba.config, "THREADING_LAYER", "default")
    monkeypatch.delenv("NUMBA_THREADING_LAYER", raising=False)
    assert prefer_workqueue_layer() == "workqueue" and numba.config.THREADING_LAYER == "workqueue"
    monkeypatch.setattr(numba.config, "THREADING_LAYER", "omp")
    monkeypatch.setenv("NUMBA_THREADING_LAYER", "omp")
    assert prefer_workqueue_layer() == "omp" and numba.config.THREADING_LAYER == "omp"
    # numba imported before the variable was set (as `davio` sets it when main() is called in-process)
    monkeypatch.setattr(numba.config, "THREADING_LAYER", "default")
    monkeypatch.setenv("NUMBA_THREADING_LAYER", "workqueue")
    assert prefer_workqueue_layer() == "workqueue" and numba.config.THREADING_LAYER == "workqueue"


def test_the_davio_command_selects_the_workqueue_layer_after_numba_was_imported(monkeypatch, capsys) -> None:
    import numba

    monkeypatch.setattr(numba.config, "THREADING_LAYER", "default")
    monkeypatch.delenv("NUMBA_THREADING_LAYER", raising=False)
    assert main(["--version"]) == 0
    assert numba.config.THREADING_LAYER == "workqueue"
    monkeypatch.setattr(numba.config, "THREADING_LAYER", "default")
    monkeypatch.setenv("NUMBA_THREADING_LAYER", "tbb")    # the user's choice stands
    assert main(["--version"]) == 0
    assert numba.config.THREADING_LAYER == "tbb"
