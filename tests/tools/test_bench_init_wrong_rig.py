"""`davio bench init-wrong-rig`: one short recording, the right rig and a deg/s gyro with the check on."""
from __future__ import annotations

import pytest

from tools.benchmarks.init_wrong_rig import measure


@pytest.mark.slow
def test_a_deg_per_second_gyro_is_refused_as_rotation_mismatch_and_the_right_rig_publishes():
    from drivers.sim import SimConfig, SimRecording

    rec = SimRecording.from_preset(SimConfig(preset="aggressive", seconds=5.0, seed=4, camera_rate_hz=10.0))
    right = measure(rec, "right", True)
    assert right["published"] > 0 and "rotation_mismatch" not in right["dynamic_rejections"]
    wrong = measure(rec, "deg/s", True)
    assert wrong["published"] == 0 and wrong["dynamic_rejections"].get("rotation_mismatch", 0) >= 1
    assert wrong["frames"] == right["frames"] and 0 < wrong["ms_median"] <= wrong["ms_p90"] <= wrong["ms_max"]
