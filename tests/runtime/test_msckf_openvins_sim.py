"""Accuracy on the first 20 s of the OpenVINS simulator's udel_gore run (skips without ../shared).

Tolerance: twice OpenVINS's own RMSE over the same 20 s, computed from its per-frame errors in
est_vs_gt.csv.gz (0.027 m, 0.31 deg at the time of writing)."""
from __future__ import annotations

import gzip

import numpy as np
import pytest
from conftest import shared_path

SECONDS = 20.0


@pytest.mark.slow
@pytest.mark.shared_data
def test_first_20s_of_udel_gore_against_openvins() -> None:
    from tools.benchmarks.openvins_sim import evaluate, load_sim_folder, run_filter

    folder = shared_path("openvins_sim", "udel_gore_mono")
    with gzip.open(folder / "est_vs_gt.csv.gz", "rt") as f:
        ov = np.loadtxt(f)
    t = ov[:, 0] - ov[0, 0]
    m = t <= SECONDS
    ov_ori = float(np.sqrt(np.mean(ov[m, 33] ** 2)))
    ov_pos = float(np.sqrt(np.mean(ov[m, 34] ** 2)))
    run = load_sim_folder(folder, max_seconds=SECONDS)
    snaps, report = run_filter(run)
    res = evaluate(run, snaps)
    assert report["divergence_resets"] == 0
    assert res["frames_evaluated"] >= 195
    assert res["rmse_pos_m"] < 2.0 * ov_pos, (res, ov_pos)
    assert res["rmse_ori_deg"] < 2.0 * ov_ori, (res, ov_ori)
    assert 0.05 < res["nees_pos"] < 6.0 and 0.3 < res["nees_ori"] < 6.0, res
