"""Preintegration of OpenVINS's simulated IMU (known white noise) against its true states.

The simulator draws white noise with the densities of sim_info.txt, so the preintegrated errors
over 0.1-0.2 s (where the bias random walk is negligible) must be consistent with our covariance:
the mean normalised estimation error squared (NEES) of the 9-vector [dphi, dv, dp] is about 9.
The true states are stored as OpenVINS JPL quaternions q_GtoI, which also exercises that convention.
"""
from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest

from runtime.geometry import jpl_xyzw_to_rot, so3_log
from runtime.imu import Preintegrator
from tests.conftest import shared_path

G_W = np.array([0.0, 0.0, -9.81])
SIGMA_W, SIGMA_A = 1.6968e-4, 2.0e-3  # sim_info.txt


def read_rows(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Stamps (decimal seconds parsed exactly into int64 ns) and the float columns."""
    stamps, rows = [], []
    with gzip.open(path, "rt") as f:
        for line in f:
            if line.startswith("#") or not line.strip():
                continue
            parts = line.split()
            sec, _, frac = parts[0].partition(".")
            stamps.append(int(sec) * 1_000_000_000 + int((frac + "000000000")[:9]))
            rows.append([float(x) for x in parts[1:]])
    return np.array(stamps, dtype=np.int64), np.array(rows)


@pytest.mark.slow
@pytest.mark.shared_data
def test_errors_against_openvins_truth_are_consistent_with_the_covariance():
    folder = shared_path("openvins_sim", "udel_gore_mono")
    imu_t, imu = read_rows(folder / "imu.csv.gz")
    gt_t, gt = read_rows(folder / "gt_cam.csv.gz")
    R_WI = np.swapaxes(jpl_xyzw_to_rot(gt[:, 0:4]), 1, 2)  # R_ItoG
    p, v, bg, ba = gt[:, 4:7], gt[:, 7:10], gt[:, 10:13], gt[:, 13:16]
    for step in (1, 2):  # 0.1 s and 0.2 s between camera states
        nees, errs = [], []
        for i0 in range(0, len(gt_t) - step, 3):
            i1 = i0 + step
            dt = (gt_t[i1] - gt_t[i0]) * 1e-9
            pre = Preintegrator(bg[i0], ba[i0], SIGMA_W, SIGMA_A).integrate(
                imu_t, imu[:, :3], imu[:, 3:], gt_t[i0], gt_t[i1])
            dR = R_WI[i0].T @ R_WI[i1]
            dv = R_WI[i0].T @ (v[i1] - v[i0] - G_W * dt)
            dp = R_WI[i0].T @ (p[i1] - p[i0] - v[i0] * dt - 0.5 * G_W * dt * dt)
            e = np.r_[so3_log(dR.T @ pre.dR), pre.dv - dv, pre.dp - dp]
            errs.append(e)
            nees.append(e @ np.linalg.solve(pre.cov, e))
        assert len(nees) > 500
        # chi-square(9): mean 9, standard error of the mean about 0.18 here (measured 9.07 and 9.05)
        assert 8.2 < np.mean(nees) < 9.9, (step, np.mean(nees))
        rms = np.sqrt(np.mean(np.square(errs), axis=0))
        np.testing.assert_allclose(rms, np.sqrt(np.diag(pre.cov)), rtol=0.15)
