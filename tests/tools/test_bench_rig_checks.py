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
    assert empty["time_offset"] == {"false_findings": 0, "right_log_s_median": None, "right_log_s_max": None,
                                    "errors": {}}


def test_summary_of_the_time_offset_solves():
    t = summarise({"ratio": [], "ratio_deg_s": [], "right": {"accepted": 3}, "right_findings": 1,
                   "log_s right": [0.01, 0.03, 0.2],
                   "offset -0.05": {"accepted_at_found_offset": 2, "time_offset": 1, "scale_unobservable": 1},
                   "offset_found_err_ms -0.05": [1.0, -3.0, 2.0], "log_s -0.05": [0.02, 0.3]},
                  15.0)["time_offset"]
    assert t["false_findings"] == 1 and t["right_log_s_median"] == pytest.approx(0.03)
    assert t["right_log_s_max"] == 0.2
    row = t["errors"]["-0.05"]
    assert row["solved"] == 2 and row["named"] == 1 and row["outcomes"]["scale_unobservable"] == 1
    assert row["found_err_ms_median"] == 2.0 and row["found_err_ms_max"] == 3.0      # distances, either sign
    assert row["log_s_median"] == pytest.approx(0.16) and row["log_s_max"] == 0.3


@pytest.mark.slow
def test_a_hand_held_recording_passes_with_the_right_rig_and_names_both_mistakes(capsys):
    assert main(["bench", "rig-checks", "--preset", "handheld", "--seconds", "8", "--every", "0.5", "--k",
                 "0.05", "--time-offset-error", "0.05,-0.05", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)["recordings"]["preset handheld"]["0.05"]
    assert s["judged"] >= 2 and s["refused_right_units"] == 0 and s["refused_deg_s"] == s["judged"]
    assert 0.8 < s["median"] < 1.5          # the chord of the camera's turn against the gyro's path
    assert s["extrinsics_false_alarms"] == 0 and s["extrinsics_named"] >= 3 and s["inverted_accepted"] == 0
    t = s["time_offset"]
    assert t["false_findings"] == 0
    late = t["errors"]["0.05"]                # the camera's stamps 50 ms late: found, and solved there
    assert late["solved"] + late["named"] >= s["windows"] // 2 and late["solved"] >= 3
    assert late["found_err_ms_max"] <= 5.0 and late["outcomes"].get("rotation_inconsistent", 0) <= 2
    early = t["errors"]["-0.05"]              # 50 ms early: found, but the IMU handed over ends too soon
    assert early["solved"] == 0 and early["named"] >= s["windows"] // 2 and early["found_err_ms_max"] <= 5.0
