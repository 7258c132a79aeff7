"""Loading a rig from any supported calibration source, and the bundled EuRoC example rig."""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

from calib.euroc import euroc_rig_from, locate, read_euroc_rig
from calib.fields import Fields, read_yaml
from calib.kalibr import kalibr_rig, read_kalibr
from calib.rig import Rig
from runtime.errors import CalibrationError

#: File names tried beside a camchain for its IMU YAML, after the name-derived candidates.
IMU_YAML_NAMES = ("kalibr_imu_chain.yaml", "imu.yaml", "imu0.yaml")


def find_imu_yaml(camchain: str | os.PathLike) -> Path | None:
    """The Kalibr IMU YAML beside a camchain, or None.

    Tries the camchain's name with ``camchain-imucam`` -> ``imu`` (Kalibr output),
    ``imucam_chain`` -> ``imu_chain`` (OpenVINS), ``camchain`` -> ``imu`` (e.g. euroc_camchain.yaml ->
    euroc_imu.yaml), then IMU_YAML_NAMES.
    """
    p = Path(camchain)
    names: list[str] = []
    for old, new in (("camchain-imucam", "imu"), ("imucam_chain", "imu_chain"), ("camchain", "imu")):
        if old in p.name:
            names.append(p.name.replace(old, new))
    names += IMU_YAML_NAMES
    for name in names:
        candidate = p.with_name(name)
        if candidate != p and candidate.is_file():
            return candidate
    return None


#: Camchain file names looked for in a folder given to load_rig (Kalibr output names are globbed).
CAMCHAIN_NAMES = ("kalibr_imucam_chain.yaml", "camchain.yaml", "camchain-imucam.yaml")


def _is_euroc_folder(folder: Path) -> bool:
    return any((folder / sub / "sensor.yaml").is_file() for sub in ("mav0/cam0", "cam0", "."))


def find_camchain(folder: str | os.PathLike) -> Path | None:
    """A Kalibr camchain in ``folder``: CAMCHAIN_NAMES, else the only ``*camchain*.yaml`` there, else None.
    Kalibr's camera-IMU run leaves ``X-camchain-imucam.yaml`` beside its input ``X-camchain.yaml`` (the
    cameras alone, no extrinsics): that pair gives the ``-imucam`` one.

    Raises CalibrationError when several ``*camchain*.yaml`` are there (which one is meant cannot be told)."""
    d = Path(folder)
    for name in CAMCHAIN_NAMES:
        if (d / name).is_file():
            return d / name
    found = sorted(f for f in d.glob("*camchain*.yaml") if f.is_file())
    imucam = [f for f in found if f.name.endswith("camchain-imucam.yaml")]
    if len(found) == 2 and len(imucam) == 1 and any(f.name == imucam[0].name.replace("-imucam", "")
                                                    for f in found):
        return imucam[0]
    if len(found) > 1 and not _is_euroc_folder(d):
        raise CalibrationError(f"{len(found)} camchains in this folder ({', '.join(f.name for f in found)}): "
                               "give the one to use as the file itself", d)
    return found[0] if len(found) == 1 else None


def load_rig(path: str | os.PathLike, imu_yaml: str | os.PathLike | None = None) -> Rig:
    """Rig from a calibration source, dispatching on what ``path`` holds.

    - a folder: EuRoC (sequence, ``mav0`` or ``cam0`` folder), or else the Kalibr camchain in it
      (:func:`find_camchain`);
    - a YAML with a top-level ``cam0``: Kalibr camchain; the IMU YAML is ``imu_yaml`` or
      :func:`find_imu_yaml`'s (withheld when there is none);
    - a YAML with ``sensor_type: camera``: EuRoC ``cam0/sensor.yaml``.
    """
    p = Path(path)
    if p.is_dir():
        camchain = find_camchain(p)
        if camchain is not None and not _is_euroc_folder(p):
            return read_kalibr(camchain, imu_yaml if imu_yaml is not None else find_imu_yaml(camchain))
        return read_euroc_rig(p)
    data = Fields(p, read_yaml(p))  # parsed once, handed to the reader
    if data.has("cam0"):
        return kalibr_rig(data, imu_yaml if imu_yaml is not None else find_imu_yaml(p))
    if data.data.get("sensor_type") == "camera":
        _, imu0, name = locate(p)
        return euroc_rig_from(data, imu0, name)
    raise CalibrationError(
        "not a recognised calibration file "
        "(expected a Kalibr camchain with cam0 or an EuRoC camera sensor.yaml)",
        p,
        "cam0",
    )


def euroc_rig() -> Rig:
    """The EuRoC MAV cam0 + imu0 rig bundled as ``calib/rigs/euroc_camchain.yaml`` / ``euroc_imu.yaml``."""
    rigs = resources.files("calib") / "rigs"
    with (
        resources.as_file(rigs / "euroc_camchain.yaml") as camchain,
        resources.as_file(rigs / "euroc_imu.yaml") as imu,
    ):
        return read_kalibr(camchain, imu)
