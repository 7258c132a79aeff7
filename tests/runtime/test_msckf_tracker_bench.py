"""The euroc-frontend benchmark end to end on the real EuRoC head (JSON contract and figures)."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from tools.benchmarks import euroc_frontend


@pytest.mark.slow
def test_euroc_frontend_json(euroc_head: Path, capsys: pytest.CaptureFixture) -> None:
    parser = argparse.ArgumentParser()
    euroc_frontend.add_arguments(parser)
    args = parser.parse_args([str(euroc_head), "--json"])
    assert euroc_frontend.run(args) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["frames"] == 95
    assert out["tracks_per_frame_min"] >= 150 and out["tracks_per_frame_mean"] >= 150
    assert out["tracker_ms_per_frame_mean"] > 0
    for mode in ("jerk", "still"):
        entry = out[f"static_{mode}"]
        assert entry["initialized"]
        assert entry["roll_pitch_err_deg_vicon2gt"] < 1.0
    # the drone sits still: the dynamic initializer must refuse
    assert out["dynamic_init"] != "initialized"


def test_missing_folder_is_reported(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    parser = argparse.ArgumentParser()
    euroc_frontend.add_arguments(parser)
    from runtime.errors import DataError

    with pytest.raises(DataError, match="nope: not a directory"):     # the CLI says it on stderr
        euroc_frontend.run(parser.parse_args([str(tmp_path / "nope")]))


@pytest.mark.slow
def test_dynamic_init_on_real_imu_window() -> None:
    from conftest import shared_path

    folder = shared_path("euroc_imu_gt", "V1_02_medium")
    out = euroc_frontend.run_dynamic(folder, window_s=10.0, max_windows=2, attempt_every=10)
    assert out["windows"] == 2 and out["initialized"] >= 1, out["rows"]
    assert out["tracks_per_frame_min"] >= 150  # tracking holds up on a moving camera
    for row in out["rows"]:
        if row["initialized"]:
            assert row["gravity_err_deg"] < 2.0
            assert row["velocity_err_mps"] < 0.2
            assert 1.8 <= row["time_to_init_s"] <= 4.0
