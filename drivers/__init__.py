"""Sources of time-stamped images and IMU samples behind one interface (DESIGN §4)."""
from __future__ import annotations

from drivers.base import Driver, IntakeReport, Policy, StreamCounts
from drivers.euroc import (
    EurocDriver,
    read_camera_timestamps,
    read_euroc_groundtruth,
    read_euroc_imu_csv,
)
from drivers.live import LiveDriver
from drivers.rosbag import RosbagDriver, is_bag
from drivers.serial_imu import SerialImu
from drivers.uvc import UvcCamera
from runtime.events import Event, Frame, ImuSample

__all__ = ["Driver", "EurocDriver", "Event", "Frame", "ImuSample", "IntakeReport", "LiveDriver", "Policy",
           "RosbagDriver", "SerialImu", "StreamCounts", "UvcCamera", "is_bag", "read_camera_timestamps",
           "read_euroc_groundtruth", "read_euroc_imu_csv"]
