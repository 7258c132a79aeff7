"""`davio bench vio-sim`: the image-based filter tracks a simulated sequence (ATE vs ground truth)."""
from __future__ import annotations

import json

import pytest

from tools.cli import main


@pytest.mark.slow
def test_vio_sim_tracks_a_simulated_sequence(capsys):
    assert main(["bench", "vio-sim", "--preset", "euroc", "--seconds", "8", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)["preset euroc"]
    assert out["resets"] == 0 and out["states"] > 100
    assert out["ate_se3_m"] < 0.1  # centimetre-level in a textured room with a GT start
    assert out["realtime_factor"] > 0
    # the filter's share includes the updates run from feed_imu (the old bench timed only feed_tracks)
    assert out["tracker_ms_per_frame_wall"] > 0
    assert out["filter_ms_per_frame_wall"] >= out["filter_updates_ms_per_frame_wall"] > 0
    assert out["tracker_ms_per_frame_wall"] + out["filter_ms_per_frame_wall"] == pytest.approx(
        out["ms_per_frame_wall"])
