"""The events every driver yields (DESIGN §4): IMU samples and camera frames, int64 ns stamps."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True, slots=True)
class ImuSample:
    """One IMU measurement in the IMU frame.

    Attributes:
        t_ns: sensor-clock time, int64 nanoseconds.
        gyro: (3,) angular rate, rad/s.
        accel: (3,) specific force, m/s^2 (reads +g upward at rest).
        lost_before: samples a live driver lost right before this one (its bounded queue overflowed):
            the interval since the previous sample is a gap, whatever its length.
    """

    t_ns: int
    gyro: np.ndarray
    accel: np.ndarray
    lost_before: int = 0


@dataclass(frozen=True, slots=True)
class Frame:
    """One camera image.

    Attributes:
        t_ns: sensor-clock time of the image (camera clock), int64 nanoseconds.
        image: (H, W) uint8 grey image, distorted as delivered by the camera.
        camera_id: index of the camera in the rig (0 for monocular).
    """

    t_ns: int
    image: np.ndarray
    camera_id: int = 0
    meta: dict = field(default_factory=dict, compare=False)


Event = ImuSample | Frame
