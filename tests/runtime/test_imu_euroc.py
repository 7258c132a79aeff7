"""Preintegration of the real EuRoC V1_02_medium IMU stream against its ground truth."""
from __future__ import annotations

import numpy as np
import pytest

from runtime.geometry import quat_wxyz_to_rot, so3_log
from runtime.imu import Preintegrator
from tests.conftest import shared_path

G_W = np.array([0.0, 0.0, -9.81])
# EuRoC's imu0/sensor.yaml noise densities
GYRO_NOISE, ACCEL_NOISE = 1.6968e-4, 2.0e-3


@pytest.mark.shared_data
def test_real_imu_reproduces_ground_truth_motion_over_one_second():
    seq = shared_path("euroc_imu_gt", "V1_02_medium")
    imu_t = np.loadtxt(seq / "imu0.csv", delimiter=",", comments="#", usecols=0, dtype=np.int64)
    imu = np.loadtxt(seq / "imu0.csv", delimiter=",", comments="#", usecols=range(1, 7))
    gt_t = np.loadtxt(seq / "groundtruth.csv", delimiter=",", comments="#", usecols=0, dtype=np.int64)
    gt = np.loadtxt(seq / "groundtruth.csv", delimiter=",", comments="#", usecols=range(1, 17))
    R = quat_wxyz_to_rot(gt[:, 3:7])
    p, v, bg, ba = gt[:, 0:3], gt[:, 7:10], gt[:, 10:13], gt[:, 13:16]
    errs, errs_no_bias, travel = [], [], []
    for i0 in range(100, len(gt_t) - 1000, 700):
        i1 = int(np.searchsorted(gt_t, gt_t[i0] + 1_000_000_000))
        dt = (gt_t[i1] - gt_t[i0]) * 1e-9
        dR = R[i0].T @ R[i1]
        dv = R[i0].T @ (v[i1] - v[i0] - G_W * dt)
        dp = R[i0].T @ (p[i1] - p[i0] - v[i0] * dt - 0.5 * G_W * dt * dt)
        travel.append(np.linalg.norm(p[i1] - p[i0]))
        for biases, out in (((bg[i0], ba[i0]), errs), ((np.zeros(3), np.zeros(3)), errs_no_bias)):
            pre = Preintegrator(*biases, GYRO_NOISE, ACCEL_NOISE).integrate(
                imu_t, imu[:, :3], imu[:, 3:], gt_t[i0], gt_t[i1])
            out.append([np.linalg.norm(so3_log(dR.T @ pre.dR)), np.linalg.norm(pre.dv - dv),
                        np.linalg.norm(pre.dp - dp)])
    errs, errs_no_bias = np.array(errs), np.array(errs_no_bias)
    assert len(errs) >= 20 and np.median(travel) > 0.5  # real motion, not a static stretch
    med = np.median(errs, axis=0)
    # measured on this sequence (1 s windows): rotation 1.3e-3 rad, velocity 0.05 m/s, position 0.023 m
    assert med[0] < 3e-3 and med[1] < 0.1 and med[2] < 0.05
    # the ground-truth biases explain most of the raw error (rotation by far the most)
    med0 = np.median(errs_no_bias, axis=0)
    assert med0[0] > 20 * med[0] and med0[1] > 4 * med[1] and med0[2] > 3 * med[2]
