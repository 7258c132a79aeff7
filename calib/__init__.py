"""Rig calibration: camera models, the camera–IMU Rig, EuRoC / Kalibr readers and the Kalibr writer."""

from calib.camera import CameraModel, Pinhole, PinholeEquidistant, PinholeRadtan, camera_class
from calib.rig import ImuNoise, Rig

__all__ = [
    "CameraModel",
    "ImuNoise",
    "Pinhole",
    "PinholeEquidistant",
    "PinholeRadtan",
    "Rig",
    "camera_class",
]
