"""Reader of EuRoC (ASL) calibration: ``mav0/cam0/sensor.yaml`` and ``mav0/imu0/sensor.yaml``.

In EuRoC every sensor's ``T_BS`` is its pose in the body frame B, and B is the IMU frame, so
T_IC = T_BI^-1 T_BC (= T_BS of cam0 when imu0's T_BS is the identity, as in all EuRoC sequences).
The files carry no camera–IMU time offset: ``time_offset_s`` is None (withheld).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from calib.fields import Fields, read_camera, read_yaml, rekeyed
from calib.rig import ImuNoise, Rig, invert_rigid, rigid_transform
from runtime.errors import CalibrationError
from runtime.file_kind import MISSING, file_problem


def locate(path: Path, camera: str = "cam0") -> tuple[Path, Path, str]:
    """(camera sensor.yaml, imu0 sensor.yaml, rig name) of a sequence, mav0, camera folder or sensor.yaml."""
    if path.is_file():
        cam_yaml = path
        mav0 = path.parent.parent
    elif (path / "mav0" / camera / "sensor.yaml").is_file():
        mav0 = path / "mav0"
        cam_yaml = mav0 / camera / "sensor.yaml"
    elif (path / camera / "sensor.yaml").is_file():
        mav0 = path
        cam_yaml = mav0 / camera / "sensor.yaml"
    elif (path / "sensor.yaml").is_file():
        cam_yaml = path / "sensor.yaml"
        mav0 = path.parent
    elif not path.exists():
        raise CalibrationError("calibration path not found", path, None)
    else:
        raise CalibrationError(
            f"not an EuRoC folder (expected mav0/{camera}/sensor.yaml, {camera}/sensor.yaml or sensor.yaml)",
            path,
            None,
        )
    name = mav0.parent.name if mav0.name == "mav0" else mav0.name
    return cam_yaml, mav0 / "imu0" / "sensor.yaml", name


def _sensor_type(f: Fields, expected: str) -> None:
    if f.has("sensor_type") and f.raw("sensor_type") != expected:
        raise f.error("sensor_type", f"expected sensor_type {expected!r}, got {f.raw('sensor_type')!r}")


def read_euroc_imu(path: str | os.PathLike) -> tuple[ImuNoise, np.ndarray | None]:
    """IMU noise and T_BI (None when withheld) from an EuRoC ``imu0/sensor.yaml``."""
    f = Fields(path, read_yaml(path))
    _sensor_type(f, "imu")
    T_BI = f.matrix("T_BS", 4, 4, nullable=True)
    if T_BI is not None:
        with rekeyed(f.path, {"T": "T_BS"}):
            T_BI = rigid_transform(T_BI, "T")
    noise_keys = {
        "gyro_noise_density": "gyroscope_noise_density",
        "gyro_random_walk": "gyroscope_random_walk",
        "accel_noise_density": "accelerometer_noise_density",
        "accel_random_walk": "accelerometer_random_walk",
        "rate_hz": "rate_hz",
    }
    values = {ours: f.number(theirs, nullable=True) for ours, theirs in noise_keys.items()}
    with rekeyed(f.path, {f"imu.{ours}": theirs for ours, theirs in noise_keys.items()}):
        return ImuNoise(**values), T_BI


def read_euroc_rig(path: str | os.PathLike, camera: str = "cam0") -> Rig:
    """Rig from EuRoC calibration files.

    Args:
        path: a sequence folder (holding ``mav0``), a ``mav0`` folder, a camera folder or a
            camera's ``sensor.yaml`` file. The IMU file is ``mav0/imu0/sensor.yaml``; when it is
            absent the IMU noise is withheld (None) and the body frame is taken as the IMU frame
            (EuRoC's definition).
        camera: the camera folder used when ``path`` is a sequence or mav0 folder (``cam0``, ``cam1``).
    """
    cam_yaml, imu_yaml, name = locate(Path(path), camera)
    return euroc_rig_from(Fields(cam_yaml, read_yaml(cam_yaml)), imu_yaml, name)


def euroc_rig_from(f: Fields, imu_yaml: Path, name: str) -> Rig:
    """Rig from an already parsed camera sensor.yaml ``f`` and the imu0 file (read when present)."""
    cam_yaml = f.path
    _sensor_type(f, "camera")
    camera = read_camera(f, "distortion_coefficients")
    rate_hz = f.number("rate_hz", nullable=True, positive=True)
    T_BC = f.matrix("T_BS", 4, 4, nullable=True)
    if T_BC is not None:
        with rekeyed(cam_yaml, {"T": "T_BS"}):
            T_BC = rigid_transform(T_BC, "T")
    imu: ImuNoise | None = None
    T_BI: np.ndarray | None = np.eye(4)
    why = file_problem(imu_yaml)
    if why not in (None, MISSING):      # a folder, a broken link: not withheld calibration
        raise CalibrationError(why, imu_yaml, None)
    if why is None:
        imu, T_BI = read_euroc_imu(imu_yaml)
    T_IC = None if T_BC is None or T_BI is None else invert_rigid(T_BI) @ T_BC
    with rekeyed(cam_yaml, {"T_IC": "T_BS", "camera_rate_hz": "rate_hz"}):
        return Rig(camera=camera, T_IC=T_IC, time_offset_s=None, imu=imu, camera_rate_hz=rate_hz, name=name)
