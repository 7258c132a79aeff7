"""Serial IMUs: Xsens Xbus MTData2 and the `$IMU` ASCII protocol, read on a thread, host-clock stamps.

    from drivers.serial_imu import SerialImu
    with SerialImu("/dev/ttyUSB0", protocol="xsens") as imu:
        sample = imu.get(timeout=0.1)   # ImuSample(t_ns host monotonic, gyro rad/s, accel m/s^2) or None
"""
from __future__ import annotations

from drivers.serial_imu.clock import DeviceClock, Unwrapper
from drivers.serial_imu.common import DeviceSample, ParserCounts
from drivers.serial_imu.reader import PROTOCOLS, SerialImu, make_parser
from drivers.serial_imu.text import TextParser
from drivers.serial_imu.xsens import XsensParser

__all__ = ["PROTOCOLS", "DeviceClock", "DeviceSample", "ParserCounts", "SerialImu", "TextParser", "Unwrapper",
           "XsensParser", "make_parser"]
