"""ImuPairer: accelerometer and gyroscope reports paired at the gyroscope stamps (no depthai needed)."""
from __future__ import annotations

import numpy as np

from drivers.imu_pairing import ImuPairer


def test_pairer_equal_and_offset_stamps() -> None:
    p = ImuPairer()
    ms = 1_000_000
    # equal stamps: exact pairs
    for k in range(3):
        p.add_accel(10 * ms + 5 * k * ms, (k, 0, 0))
        p.add_gyro(10 * ms + 5 * k * ms, (0, k, 0))
    out = p.pop()
    assert [s.t_ns for s in out] == [10 * ms, 15 * ms, 20 * ms]
    assert [s.accel[0] for s in out] == [0, 1, 2] and p.interpolated == 0
    # gyro 2 ms after each accel: interpolated, the last waits for the next accel
    q = ImuPairer()
    q.add_gyro(1 * ms, (9, 9, 9))  # before any accel: dropped
    for k in range(4):
        q.add_accel(10 * ms + 5 * k * ms, (10.0 * k, 0, 0))
        q.add_gyro(12 * ms + 5 * k * ms, (k, 0, 0))
    out = q.pop()
    assert [s.t_ns for s in out] == [12 * ms, 17 * ms, 22 * ms]
    np.testing.assert_allclose([s.accel[0] for s in out], [4.0, 14.0, 24.0])
    assert q.unpaired == 1 and q.interpolated == 3 and q.counts()["waiting"] == 1
    q.add_accel(10 * ms, (0, 0, 0))  # repeated stamp
    assert q.repeated == 1


def test_pairer_drops_and_counts_the_oldest_waiting_gyro_reports() -> None:
    """An accelerometer that stopped: the gyroscope reports beyond max_pending are dropped and counted."""
    p = ImuPairer(max_pending=4)
    p.add_accel(0, (0, 0, 9.81))
    for k in range(1, 7):  # six reports after the last accelerometer report: none can be paired yet
        p.add_gyro(k * 1000, (k, 0, 0))
    assert p.pop() == [] and p.unpaired == 2 and p.counts()["waiting"] == 4
    p.add_accel(10_000, (0, 0, 9.81))
    out = p.pop()
    assert [s.t_ns for s in out] == [3000, 4000, 5000, 6000]  # the two oldest went, the rest pair
    np.testing.assert_allclose([s.gyro[0] for s in out], [3, 4, 5, 6])
    assert p.paired == 4 and p.interpolated == 4 and p.counts()["waiting"] == 0
