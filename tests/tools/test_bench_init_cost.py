"""`davio bench init-cost`: the errors against the truth it reports, on states whose errors are known."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from runtime.geometry import so3_exp
from runtime.msckf.init_common import InitResult
from tools.benchmarks.init_cost import _errors, _stats


def test_errors_are_the_gravity_tilt_and_the_body_frame_velocity_difference():
    R_WI = so3_exp(np.array([0.2, -0.1, 1.3]))
    v_W = np.array([0.5, -0.3, 0.1])
    truth = SimpleNamespace(sample=lambda t: SimpleNamespace(R=R_WI[None], v=v_W[None]))
    # yaw is a gauge of O: a state yawed by 40 deg with the same body-frame velocity has no error
    yaw = so3_exp(np.array([0.0, 0.0, np.radians(40.0)]))
    same = InitResult(0, yaw @ R_WI, np.zeros(3), yaw @ v_W, np.zeros(3), np.zeros(3), None, "dynamic")
    assert _errors(same, truth) == pytest.approx({"velocity_m_s": 0.0, "gravity_deg": 0.0}, abs=1e-6)
    # tilted by 3 deg about a horizontal body axis, and 0.2 m/s off along body z
    up_I = R_WI[2, :]
    axis = np.cross(up_I, [1.0, 0.0, 0.0])
    tilted = R_WI @ so3_exp(np.radians(3.0) * axis / np.linalg.norm(axis))
    v_wrong = tilted @ (R_WI.T @ v_W + np.array([0.0, 0.0, 0.2]))
    off = InitResult(0, tilted, np.zeros(3), v_wrong, np.zeros(3), np.zeros(3), None, "dynamic")
    assert _errors(off, truth) == pytest.approx({"velocity_m_s": 0.2, "gravity_deg": 3.0}, rel=1e-6)


def test_stats_of_no_attempt_and_of_some():
    assert _stats([]) == {"n": 0, "median_ms": None, "p90_ms": None, "max_ms": None}
    s = _stats([1.0, 2.0, 3.0, 10.0])
    assert s["n"] == 4 and s["median_ms"] == 2.5 and s["max_ms"] == 10.0
    assert s["p90_ms"] == pytest.approx(np.percentile([1, 2, 3, 10], 90))
