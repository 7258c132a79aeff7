"""Sources of time-stamped images and IMU samples behind one interface (DESIGN §4).

The names below are imported on first use (PEP 562): importing one driver module (or the simulator's
presets, which the `davio` command reads to build its options) does not import every driver.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from runtime.lazy_exports import lazy_exports

_EXPORTS = {
    "Driver": "drivers.base", "IntakeReport": "drivers.base", "Policy": "drivers.base",
    "StreamCounts": "drivers.base",
    "EurocDriver": "drivers.euroc", "read_camera_timestamps": "drivers.euroc",
    "read_euroc_groundtruth": "drivers.euroc", "read_euroc_imu_csv": "drivers.euroc",
    "LiveDriver": "drivers.live",
    "RosbagDriver": "drivers.rosbag", "is_bag": "drivers.rosbag",
    "SerialImu": "drivers.serial_imu",
    "UvcCamera": "drivers.uvc",
    "Event": "runtime.events", "Frame": "runtime.events", "ImuSample": "runtime.events",
}

if TYPE_CHECKING:
    from drivers.base import Driver, IntakeReport, Policy, StreamCounts
    from drivers.euroc import EurocDriver, read_camera_timestamps, read_euroc_groundtruth, read_euroc_imu_csv
    from drivers.live import LiveDriver
    from drivers.rosbag import RosbagDriver, is_bag
    from drivers.serial_imu import SerialImu
    from drivers.uvc import UvcCamera
    from runtime.events import Event, Frame, ImuSample

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

__all__ = ["Driver", "EurocDriver", "Event", "Frame", "ImuSample", "IntakeReport", "LiveDriver", "Policy",
           "RosbagDriver", "SerialImu", "StreamCounts", "UvcCamera", "is_bag", "read_camera_timestamps",
           "read_euroc_groundtruth", "read_euroc_imu_csv"]
