"""Rig calibration: camera models, the camera–IMU Rig, EuRoC / Kalibr readers and the Kalibr writer."""

from calib.camera import (
    CameraModel,
    Pinhole,
    PinholeEquidistant,
    PinholeRadtan,
    PinholeRational,
    camera_class,
)
from calib.euroc import read_euroc_rig
from calib.io import euroc_rig, find_camchain, find_imu_yaml, load_rig
from calib.kalibr import read_kalibr, read_kalibr_imu, write_kalibr
from calib.rig import ImuNoise, Rig

__all__ = [
    "CameraModel",
    "ImuNoise",
    "Pinhole",
    "PinholeEquidistant",
    "PinholeRadtan",
    "PinholeRational",
    "Rig",
    "camera_class",
    "euroc_rig",
    "find_camchain",
    "find_imu_yaml",
    "load_rig",
    "read_euroc_rig",
    "read_kalibr",
    "read_kalibr_imu",
    "write_kalibr",
]
