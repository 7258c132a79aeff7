"""The simulator's default rig: EuRoC cam0 + ADIS16448 IMU (calib's EuRoC rig when available)."""

from __future__ import annotations

import numpy as np

T_IC_EUROC = np.array(
    [
        [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975],
        [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768],
        [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
"""EuRoC cam0 pose in the IMU/body frame (cam0/sensor.yaml T_BS)."""


def euroc_default_rig():
    """The EuRoC MAV rig (cam0 752x480 radtan, T_IC, ADIS16448 noise, 20 Hz camera, zero time offset).

    Uses `calib.euroc_rig` when the calib package provides it, else builds the same values here.
    """
    import calib

    provided = getattr(calib, "euroc_rig", None)
    if provided is not None:
        rig = provided() if callable(provided) else provided
        if rig.time_offset_s is None:
            rig = rig.replace(time_offset_s=0.0)
        return rig
    cam = calib.PinholeRadtan(
        752, 480, 458.654, 457.296, 367.215, 248.375, [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
    )
    imu = calib.ImuNoise(
        gyro_noise_density=1.6968e-04,
        gyro_random_walk=1.9393e-05,
        accel_noise_density=2.0e-3,
        accel_random_walk=3.0e-3,
        rate_hz=200.0,
    )
    return calib.Rig(
        camera=cam,
        T_IC=T_IC_EUROC.copy(),
        time_offset_s=0.0,
        imu=imu,
        camera_rate_hz=20.0,
        name="EuRoC MAV cam0 + imu0",
    )
