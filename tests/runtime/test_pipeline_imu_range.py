"""VioPipeline's IMU range gate: samples beyond any MEMS IMU never reach the start-up or the filters,
and a live driver's gap flag on a dropped sample moves to the next one."""
from __future__ import annotations

import numpy as np

from calib.io import euroc_rig
from runtime.config import DavioConfig
from runtime.events import ImuSample
from runtime.pipeline import MAX_ACCEL_M_S2, MAX_GYRO_RAD_S, VioPipeline


def test_out_of_range_samples_are_dropped_and_the_gap_flag_carried() -> None:
    pipe = VioPipeline(euroc_rig(), None, DavioConfig())
    seen: list[ImuSample] = []
    feed = pipe.startup.native.feed_imu
    pipe.startup.native.feed_imu = lambda s: (seen.append(s), feed(s))[1]
    g, a = np.zeros(3), np.array([0.0, 0.0, 9.81])
    pipe.on_imu(ImuSample(1_000_000, g, a))
    pipe.on_imu(ImuSample(6_000_000, g, np.array([0.0, MAX_ACCEL_M_S2 * 1.01, 9.81]), lost_before=3))
    pipe.on_imu(ImuSample(11_000_000, np.array([0.0, -MAX_GYRO_RAD_S * 2, 0.0]), a))
    pipe.on_imu(ImuSample(16_000_000, np.array([0.0, MAX_GYRO_RAD_S, 0.0]), a))   # at the limit: kept
    pipe.on_imu(ImuSample(21_000_000, g, a))
    assert [s.t_ns for s in seen] == [1_000_000, 16_000_000, 21_000_000]
    assert [s.lost_before for s in seen] == [0, 3, 0]
    assert pipe.stats.imu_out_of_range == 2
