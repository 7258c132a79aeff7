"""`davio bench gyro-scale`: the summary's arithmetic, and a short hand-held recording end to end."""
from __future__ import annotations

import json

import numpy as np
import pytest

from tools.benchmarks.gyro_scale import summarise
from tools.cli import main


def test_summary_counts_refusals_on_either_side_of_the_bound():
    s = summarise({"ratio": [1.0, 1.2, 16.0], "ratio_deg_s": [57.0, 69.0, 900.0]}, 15.0)
    assert s["judged"] == 3 and s["refused_right_units"] == 1 and s["refused_deg_s"] == 3
    assert s["min"] == 1.0 and s["max"] == 16.0 and s["median"] == 1.2
    assert s["p99"] == pytest.approx(np.percentile([1.0, 1.2, 16.0], 99))
    empty = summarise({"ratio": [], "ratio_deg_s": []}, 15.0)
    assert empty["judged"] == 0 and empty["max"] is None and empty["refused_deg_s"] == 0


@pytest.mark.slow
def test_a_hand_held_recording_passes_with_rad_s_and_is_refused_in_deg_s(capsys):
    assert main(["bench", "gyro-scale", "--preset", "handheld", "--seconds", "5", "--every", "1", "--k",
                 "0.05,1", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    for k in ("0.05", "1.0"):
        s = out["recordings"]["preset handheld"][k]
        assert s["judged"] >= 2 and s["refused_right_units"] == 0 and s["refused_deg_s"] == s["judged"]
        assert 0.8 < s["median"] < 1.5          # the chord of the camera's turn against the gyro's path
