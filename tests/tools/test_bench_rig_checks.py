"""`davio bench rig-checks`: the summary's arithmetic, and a short hand-held recording end to end."""
from __future__ import annotations

import json

import numpy as np
import pytest

from tools.benchmarks.rig_checks import summarise
from tools.cli import main


def test_summary_counts_refusals_on_either_side_of_the_bound():
    s = summarise({"ratio": [1.0, 1.2, 16.0], "ratio_deg_s": [57.0, 69.0, 900.0],
                   "right": {"accepted": 2, "extrinsics_rotation": 1},
                   "inverted": {"extrinsics_rotation": 2, "gyro_bias_step": 1}}, 15.0)
    assert s["judged"] == 3 and s["refused_right_units"] == 1 and s["refused_deg_s"] == 3
    assert s["min"] == 1.0 and s["max"] == 16.0 and s["median"] == 1.2
    assert s["p99"] == pytest.approx(np.percentile([1.0, 1.2, 16.0], 99))
    assert s["windows"] == 3 and s["extrinsics_false_alarms"] == 1 and s["extrinsics_named"] == 2
    assert s["inverted_accepted"] == 0
    empty = summarise({"ratio": [], "ratio_deg_s": []}, 15.0)
    assert empty["judged"] == 0 and empty["max"] is None and empty["refused_deg_s"] == 0


@pytest.mark.slow
def test_a_hand_held_recording_passes_with_the_right_rig_and_names_both_mistakes(capsys):
    assert main(["bench", "rig-checks", "--preset", "handheld", "--seconds", "8", "--every", "0.5", "--k",
                 "0.05", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)["recordings"]["preset handheld"]["0.05"]
    assert s["judged"] >= 2 and s["refused_right_units"] == 0 and s["refused_deg_s"] == s["judged"]
    assert 0.8 < s["median"] < 1.5          # the chord of the camera's turn against the gyro's path
    assert s["extrinsics_false_alarms"] == 0 and s["extrinsics_named"] >= 3 and s["inverted_accepted"] == 0
