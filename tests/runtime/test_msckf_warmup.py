"""Kernel warm-up: after the estimator is built, its per-frame path loads no further numba specialisation.

Each case runs in a fresh process (kernels loaded once stay loaded): without the warm-up the same run does
load kernels during its frames, so the check can fail."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

SCRIPT = """
import json, sys
sys.path[:0] = [{root!r}, {tests!r}]
from runtime.msckf import measurement, propagator, state_helper, track_linearization, triangulation
from runtime.msckf import update_slam
from runtime.msckf.config import MsckfConfig
from runtime.msckf.estimator import MsckfEstimator
from test_msckf_estimator import _init, _rig, _run, _stream
import numpy as np

KERNELS = [track_linearization.msckf_rows_packed, track_linearization.linearize_all_packed,
           update_slam.slam_rows, update_slam.assemble_slam_rows, update_slam.anchor_change_kernel,
           propagator.propagate_interval,
           measurement.projected_mahalanobis, measurement.givens_left_nullspace,
           measurement.feature_jacobians,
           triangulation.triangulate, state_helper._mirror_lower_to_upper]
est = MsckfEstimator(_rig(), MsckfConfig(warm_kernels={warm}, dt_slam_delay=1.0))
_init(est, np.zeros(3))
before = [len(k.signatures) for k in KERNELS]
imu, frames = _stream(3.0)
snaps = _run(est, imu, frames)
after = [len(k.signatures) for k in KERNELS]
print(json.dumps({{"before": before, "after": after, "warmup_s": est.warmup_s, "frames": len(snaps),
                  "slam": est.counters.slam_initialized, "msckf": est.counters.msckf_features_used}}))
"""


def _run_case(warm: bool) -> dict:
    code = SCRIPT.format(root=str(ROOT), tests=str(ROOT / "tests" / "runtime"), warm=warm)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_the_frames_after_a_warm_up_load_no_kernel_and_without_it_they_do() -> None:
    warm = _run_case(True)
    assert warm["msckf"] > 0 and warm["slam"] > 0, warm      # the run exercised both update paths
    assert warm["warmup_s"] > 0
    assert warm["after"] == warm["before"], warm
    cold = _run_case(False)
    assert cold["warmup_s"] == 0
    assert sum(cold["after"]) > sum(cold["before"]), cold
