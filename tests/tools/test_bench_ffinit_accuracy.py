"""`davio bench ffinit-accuracy`: error helpers against closed forms, and the sweep on a short preset."""
from __future__ import annotations

import json

import numpy as np
import pytest

from tools.benchmarks.ffinit_accuracy import window_frame_indices
from tools.cli import main


def test_window_frame_indices():
    stamps = np.arange(0, 3_000_000_000, 50_000_000, dtype=np.int64)  # 20 Hz
    assert window_frame_indices(stamps, 100_000_000) == [2, 6, 10, 14, 18]
    assert window_frame_indices(stamps[::5], 0) is None  # 4 Hz: no image near 0.2 s


@pytest.mark.slow
def test_sweep_on_a_short_preset(capsys, tmp_path):
    out_file = tmp_path / "acc.json"
    assert main(["bench", "ffinit-accuracy", "--preset", "euroc", "--seconds", "8", "--every", "2",
                 "--k", "0,0.15,1", "--json", "--out", str(out_file)]) == 0
    out = json.loads(capsys.readouterr().out)
    rows = out["recordings"]["preset euroc"]
    assert set(rows) == {"0.0", "0.15", "1.0"}
    assert rows["0.0"]["windows"] == rows["1.0"]["windows"] >= 3
    exact, mid = rows["0.0"], rows["0.15"]
    assert exact["accepted"] >= 1 and mid["accepted"] >= 1
    # exact DA3 poses (same draws otherwise): the tilt is nearly exact (the synthetic IMU's noise and
    # biases remain); 0.15 x the upper-bound errors still pass the DA3-gyro consistency gate
    assert exact["gravity_err_deg_median"] < 0.5
    # at the upper-bound errors the DA3-gyro consistency gate refuses every window
    per = json.loads(out_file.read_text())["per_window"]["preset euroc"]["1.0"]
    assert rows["1.0"]["accepted"] == 0
    assert {r["reason"] for r in per} <= {"rotation_inconsistent", "small_baseline"}
    assert any(r["reason"] == "rotation_inconsistent" for r in per)


def test_bad_fields_are_a_clear_error(capsys):
    assert main(["bench", "ffinit-accuracy", "--fields", "focal_log_sigma"]) == 1
    assert "pose-error knob" in capsys.readouterr().err


@pytest.mark.slow
def test_without_accelerometer_bias_and_da3_pose_errors_the_scale_is_right(capsys, tmp_path):
    """The wrong scales at the calibrated DA3 errors come from the accelerometer bias (BENCHMARKS.md
    "Gates that refuse a wrong scale"): with neither, every accepted window's scale is within 5 %."""
    out_file = tmp_path / "acc.json"
    assert main(["bench", "ffinit-accuracy", "--preset", "handheld", "--seconds", "8", "--every", "2",
                 "--k", "0", "--sim-accel-bias-sigma", "0", "--max-scale-uncertainty", "inf",
                 "--json", "--out", str(out_file)]) == 0
    rows = json.loads(out_file.read_text())["per_window"]["preset handheld"]["0.0"]
    acc = [r for r in rows if r["accepted"]]
    assert len(acc) >= 2
    assert max(r["abs_log_scale_err"] for r in acc) < 0.05


def test_sim_bias_option_is_refused_for_a_real_imu(capsys):
    assert main(["bench", "ffinit-accuracy", "--sequence", "x", "--sim-accel-bias-sigma", "0"]) == 1
    assert "real IMU" in capsys.readouterr().err
