"""Kalibr camchain / imu YAML: reader (Kalibr and OpenVINS flavours) and writer.

Camchain keys per camera (``cam0``): ``camera_model`` (pinhole), ``intrinsics`` [fx, fy, cx, cy],
``resolution`` [w, h], ``distortion_model`` (radtan | equidistant, aliases equi / fisheye /
radial-tangential, none; and DAVIO's ``rational``, OpenCV's eight coefficients k1 k2 p1 p2 k3 k4 k5 k6 of
a factory calibration, which neither Kalibr nor OpenVINS reads), ``distortion_coeffs``, extrinsics as
Kalibr's ``T_cam_imu`` (= T_CI) or OpenVINS's ``T_imu_cam`` (= T_IC), ``timeshift_cam_imu``
(t_imu = t_cam + shift, seconds).
DAVIO extension keys, ignored by Kalibr and OpenVINS: ``rate_hz`` (camera rate) and ``rig_name``.
IMU file keys (``imu0``): ``accelerometer_noise_density``, ``accelerometer_random_walk``,
``gyroscope_noise_density``, ``gyroscope_random_walk``, ``update_rate``.

The writer's files load in Kalibr (PyYAML) and in OpenVINS 2.7 (OpenCV's FileStorage, which opens only a
file starting with ``%YAML`` and refuses block sequences at their key's indentation): each camera also
gets ``rostopic`` and ``cam_overlaps``, the IMU file ``rostopic`` and the IMU intrinsics OpenVINS 2.7
requires (``model: kalibr``, identity ``Tw``, ``Ta``, ``R_IMUtoGYRO``, ``R_IMUtoACC``, zero ``Tg``: no IMU
intrinsics, DAVIO's model). OpenVINS reads ``T_cam_imu`` as well as its own ``T_imu_cam``.

Withheld values: absent extrinsics / timeshift (as in Kalibr's camera-only output) and null
values read as None; any other absent key is an error.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Literal

import numpy as np
import yaml

from calib.camera import Pinhole, PinholeEquidistant, PinholeRadtan, PinholeRational
from calib.fields import Fields, read_camera, read_yaml, rekeyed, write_text_atomic
from calib.rig import IMU_FIELDS, ImuNoise, Rig, rigid_transform
from runtime.errors import CalibrationError

#: Kalibr imu0 key for each ImuNoise field.
KALIBR_IMU_KEYS = {
    "gyro_noise_density": "gyroscope_noise_density",
    "gyro_random_walk": "gyroscope_random_walk",
    "accel_noise_density": "accelerometer_noise_density",
    "accel_random_walk": "accelerometer_random_walk",
    "rate_hz": "update_rate",
}
#: Extrinsics from two files (or two keys) must agree this well (max abs entry).
EXTRINSICS_AGREEMENT = 1e-5


def read_kalibr_imu(path: str | os.PathLike, imu: str = "imu0") -> ImuNoise:
    """IMU noise model from a Kalibr imu YAML (``imu0`` block); null values are withheld (None)."""
    f = Fields(path, read_yaml(path)).sub(imu)
    values = {ours: f.number(theirs, nullable=True) for ours, theirs in KALIBR_IMU_KEYS.items()}
    with rekeyed(f.path, {f"imu.{ours}": f.key(theirs) for ours, theirs in KALIBR_IMU_KEYS.items()}):
        return ImuNoise(**values)


def _read_T_IC(f: Fields) -> np.ndarray | None:
    found: dict[str, np.ndarray] = {}
    for key in ("T_cam_imu", "T_imu_cam"):
        if f.has(key):
            M = f.matrix(key, 4, 4, nullable=True)
            if M is not None:
                with rekeyed(f.path, {"T": f.key(key)}):
                    M = np.array(rigid_transform(M, "T"))
                # a true matrix inverse keeps write -> read exact for files with rounded rotations
                found[key] = np.linalg.inv(M) if key == "T_cam_imu" else M
    if len(found) == 2 and np.max(np.abs(found["T_cam_imu"] - found["T_imu_cam"])) > EXTRINSICS_AGREEMENT:
        raise f.error(
            "T_imu_cam", "T_cam_imu and T_imu_cam are both given and are not inverses of each other"
        )
    return found.get("T_cam_imu", found.get("T_imu_cam"))


def read_kalibr(
    camchain_yaml: str | os.PathLike, imu_yaml: str | os.PathLike | None = None, camera: str = "cam0"
) -> Rig:
    """Rig from a Kalibr camchain YAML (camera ``camera``) and optionally a Kalibr imu YAML.

    Without ``imu_yaml`` the IMU noise is withheld (None). Accepts Kalibr's ``T_cam_imu`` and
    OpenVINS's ``T_imu_cam``; an OpenCV ``%YAML:1.0`` first line is tolerated.
    """
    return kalibr_rig(Fields(camchain_yaml, read_yaml(camchain_yaml)), imu_yaml, camera)


#: Keys of a camchain's camera block that DAVIO reads.
CAMERA_KEYS = ("camera_model", "intrinsics", "resolution", "distortion_model", "distortion_coeffs",
               "T_cam_imu", "T_imu_cam", "timeshift_cam_imu", "rate_hz", "rig_name")


def _refuse_misspelt_keys(f: Fields) -> None:
    """A key close to one DAVIO reads (``T_cam_imuu``) but not one of them is a CalibrationError: a
    misspelt extrinsics or time-shift key would otherwise read as withheld calibration. Other keys are
    left alone: those Kalibr and OpenVINS write that DAVIO does not read (``rostopic``, ``cam_overlaps``,
    ``T_cn_cnm1``) and extensions of a known key (``T_cam_imu_gt``, ``intrinsics_cov``)."""
    import difflib

    for key in f.data:
        if not isinstance(key, str) or key in CAMERA_KEYS or key in ("rostopic", "cam_overlaps") \
                or key.startswith("T_cn_cnm") or any(key.startswith(k + "_") for k in CAMERA_KEYS):
            continue
        close = difflib.get_close_matches(key, CAMERA_KEYS, n=1, cutoff=0.8)
        if close:
            raise f.error(key, f"unknown key; did you mean {close[0]!r}? (a misspelt key would read as "
                               "withheld calibration)")


def kalibr_rig(top: Fields, imu_yaml: str | os.PathLike | None = None, camera: str = "cam0") -> Rig:
    """Rig from an already parsed camchain ``top`` (see :func:`calib.io.load_rig`), as read_kalibr."""
    camchain_yaml = top.path
    f = top.sub(camera)
    _refuse_misspelt_keys(f)
    cam = read_camera(f, "distortion_coeffs")
    T_IC = _read_T_IC(f)
    time_offset = f.number("timeshift_cam_imu", nullable=True, optional=True)
    rate_hz = f.number("rate_hz", nullable=True, optional=True, positive=True)
    name = f.raw("rig_name", optional=True)
    if name is not None and not isinstance(name, str):
        raise f.error("rig_name", f"expected a string, got {name!r}")
    imu = None if imu_yaml is None else read_kalibr_imu(imu_yaml)
    ext_key = next((k for k in ("T_imu_cam", "T_cam_imu") if f.has(k)), "T_imu_cam")
    with rekeyed(f.path, {"time_offset_s": f.key("timeshift_cam_imu"), "T_IC": f.key(ext_key),
                          "camera_rate_hz": f.key("rate_hz")}):
        return Rig(
            camera=cam,
            T_IC=T_IC,
            time_offset_s=time_offset,
            imu=imu,
            camera_rate_hz=rate_hz,
            name=name if name is not None else Path(camchain_yaml).stem,
        )


class _FlowList(list):
    """A list dumped in YAML flow style ([a, b, c])."""


class _Dumper(yaml.SafeDumper):
    """Block sequences indented under their key (OpenCV's YAML parser refuses them otherwise)."""

    def increase_indent(self, flow: bool = False, indentless: bool = False) -> None:
        return super().increase_indent(flow, False)


DEFAULT_CAM_TOPIC = "/cam0/image_raw"
DEFAULT_IMU_TOPIC = "/imu0"
#: OpenVINS 2.7's IMU intrinsics (StateOptions ``model``, VioManagerOptions ``Tw`` ... ``Tg``), all required
#: by its parser: the values of an IMU without intrinsic errors.
OPENVINS_IMU_INTRINSICS = {"model": "kalibr", "Tw": np.eye(3), "R_IMUtoGYRO": np.eye(3), "Ta": np.eye(3),
                           "R_IMUtoACC": np.eye(3), "Tg": np.zeros((3, 3))}


_Dumper.add_representer(
    _FlowList, lambda d, data: d.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=True)
)


def _camera_block(rig: Rig, extrinsics_key: str, topic: str) -> dict:
    cam = rig.camera
    block: dict = {}
    if rig.T_IC is not None:
        T = np.linalg.inv(rig.T_IC) if extrinsics_key == "T_cam_imu" else np.array(rig.T_IC)
        block[extrinsics_key] = [_FlowList(float(v) for v in row) for row in T]
    block["camera_model"] = "pinhole"
    if cam is None:
        block["intrinsics"] = None
    else:
        if isinstance(cam, PinholeRadtan):
            coeffs = cam.distortion.tolist()
            if len(coeffs) == 5:
                if coeffs[4] != 0.0:
                    raise CalibrationError(
                        "Kalibr's radtan model has no k3 term; this camera's k3 is not zero",
                        None,
                        "distortion",
                    )
                coeffs = coeffs[:4]
        elif isinstance(cam, (PinholeEquidistant, Pinhole, PinholeRational)):
            coeffs = cam.distortion.tolist()    # rational: DAVIO reads it back; Kalibr and OpenVINS do not
        else:
            raise CalibrationError(f"cannot write {type(cam).__name__} to Kalibr", None, "camera")
        block["distortion_coeffs"] = _FlowList(coeffs)
        block["distortion_model"] = cam.distortion_model
        block["intrinsics"] = _FlowList([cam.fx, cam.fy, cam.cx, cam.cy])
        block["resolution"] = _FlowList([cam.width, cam.height])
    if rig.time_offset_s is not None:
        block["timeshift_cam_imu"] = rig.time_offset_s
    if rig.camera_rate_hz is not None:
        block["rate_hz"] = rig.camera_rate_hz
    if rig.name:
        block["rig_name"] = rig.name
    block["cam_overlaps"] = _FlowList()
    block["rostopic"] = topic
    return block


YAML_DIRECTIVE = "%YAML 1.1\n---\n"
"""First lines of every written file: OpenCV 3.x/4.x's FileStorage (OpenVINS 2.7's reader) opens a file
only when it starts with "%YAML"; PyYAML (Kalibr's) refuses OpenCV's own "%YAML:1.0" but reads this."""


def _header(comment: str | None) -> str:
    if not comment:
        return YAML_DIRECTIVE
    return YAML_DIRECTIVE + "".join(f"# {line}".rstrip() + "\n" for line in comment.splitlines())


def write_kalibr(
    rig: Rig,
    camchain_path: str | os.PathLike,
    imu_path: str | os.PathLike | None = None,
    extrinsics_key: Literal["T_cam_imu", "T_imu_cam"] = "T_cam_imu",
    comment: str | None = None,
    cam_topic: str = DEFAULT_CAM_TOPIC,
    imu_topic: str = DEFAULT_IMU_TOPIC,
) -> None:
    """Write ``rig`` as a Kalibr camchain (``cam0``) and optionally a Kalibr imu YAML (``imu0``).

    Withheld values: extrinsics and timeshift are left out (as in Kalibr's camera-only output);
    a withheld camera is written as ``intrinsics: null``; withheld IMU fields as null. Floats are
    written with full precision, so :func:`read_kalibr` gives back the same rig. Writes are atomic.

    Args:
        extrinsics_key: ``T_cam_imu`` (Kalibr, T_CI) or ``T_imu_cam`` (OpenVINS, T_IC).
        comment: optional text written as ``#`` lines at the top of each file.
        cam_topic, imu_topic: the ``rostopic`` entries (Kalibr and OpenVINS's ROS nodes read them).
    """
    if extrinsics_key not in ("T_cam_imu", "T_imu_cam"):
        raise ValueError(f"extrinsics_key must be 'T_cam_imu' or 'T_imu_cam', got {extrinsics_key!r}")
    with rekeyed(camchain_path, {"distortion": "cam0.distortion_coeffs", "camera": "cam0"}):
        camchain = {"cam0": _camera_block(rig, extrinsics_key, cam_topic)}
    text = yaml.dump(camchain, Dumper=_Dumper, sort_keys=False, default_flow_style=False)
    write_text_atomic(camchain_path, _header(comment) + text)
    if imu_path is not None:
        imu = rig.imu if rig.imu is not None else ImuNoise()
        block = {KALIBR_IMU_KEYS[name]: getattr(imu, name) for name in IMU_FIELDS}
        block = {k: block[k] for k in sorted(block)}
        block["rostopic"] = imu_topic
        for key, value in OPENVINS_IMU_INTRINSICS.items():
            block[key] = value if isinstance(value, str) else [_FlowList(map(float, row)) for row in value]
        text = yaml.dump({"imu0": block}, Dumper=_Dumper, sort_keys=False, default_flow_style=False)
        write_text_atomic(imu_path, _header(comment) + text)
