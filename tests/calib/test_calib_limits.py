"""Calibration files that are not UTF-8, too large, deeply nested, or hold impossible numbers."""
from __future__ import annotations

from importlib import resources
from pathlib import Path

import pytest
import yaml

import calib.fields
from calib import load_rig, read_euroc_rig, read_kalibr, read_kalibr_imu
from calib.fields import MAX_CALIBRATION_BYTES, read_yaml
from calib.rig import ImuNoise
from runtime.errors import CalibrationError

RIGS = resources.files("calib") / "rigs"
CAMCHAIN = (RIGS / "euroc_camchain.yaml").read_text()
IMU = (RIGS / "euroc_imu.yaml").read_text()

EUROC_CAM = """%YAML:1.0
sensor_type: camera
comment: VI-Sensor cam0 (MT9M034)
T_BS:
  cols: 4
  rows: 4
  data: [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975,
         0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768,
        -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949,
         0.0, 0.0, 0.0, 1.0]
rate_hz: 20
resolution: [752, 480]
camera_model: pinhole
intrinsics: [458.654, 457.296, 367.215, 248.375]
distortion_model: radial-tangential
distortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
"""
EUROC_IMU = """%YAML:1.0
sensor_type: imu
T_BS:
  cols: 4
  rows: 4
  data: [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]
rate_hz: 200
gyroscope_noise_density: 1.6968e-04
gyroscope_random_walk: 1.9393e-05
accelerometer_noise_density: 2.0000e-3
accelerometer_random_walk: 3.0000e-3
"""


def _euroc(tmp_path: Path, cam: str = EUROC_CAM, imu: str = EUROC_IMU) -> Path:
    for name, text in (("cam0", cam), ("imu0", imu)):
        (tmp_path / "mav0" / name).mkdir(parents=True, exist_ok=True)
        (tmp_path / "mav0" / name / "sensor.yaml").write_text(text)
    return tmp_path


def test_latin1_byte_in_a_comment_is_tolerated(tmp_path: Path) -> None:
    clean = tmp_path / "clean.yaml"
    clean.write_text(CAMCHAIN)
    latin = tmp_path / "latin.yaml"
    latin.write_bytes(b"# calibr\xe9 le 3 mai\n" + CAMCHAIN.encode())
    assert read_kalibr(latin).isclose(read_kalibr(clean))


def test_latin1_byte_in_a_value_names_offset_and_line(tmp_path: Path) -> None:
    raw = CAMCHAIN.replace("rig_name: euroc_mav_cam0", "rig_name: cam\xe9ra").encode("latin-1")
    p = tmp_path / "camchain.yaml"
    p.write_bytes(raw)
    offset = raw.index(b"\xe9")
    line = raw[:offset].count(b"\n") + 1
    with pytest.raises(CalibrationError) as err:
        read_kalibr(p)
    assert err.value.path == str(p)
    assert f"byte 0xe9 at offset {offset} (line {line}) is not UTF-8" in str(err.value)
    assert "save the file as UTF-8" in str(err.value)


def test_euroc_sensor_yaml_with_latin1_comment(tmp_path: Path) -> None:
    ref = read_euroc_rig(_euroc(tmp_path / "a"))
    cam = EUROC_CAM.replace("comment: VI-Sensor cam0 (MT9M034)", "# cam\xe9ra de gauche")
    folder = tmp_path / "b"
    _euroc(folder)
    (folder / "mav0" / "cam0" / "sensor.yaml").write_bytes(cam.encode("latin-1"))
    assert read_euroc_rig(folder).isclose(ref)


def test_oversized_file_is_refused_before_it_is_parsed(tmp_path: Path, monkeypatch) -> None:
    p = tmp_path / "sensor.yaml"
    p.write_bytes(CAMCHAIN.encode() + b"# " + b"x" * MAX_CALIBRATION_BYTES + b"\n")

    def no_parse(*args: object, **kwargs: object) -> None:
        raise AssertionError("parsed an oversized file")

    monkeypatch.setattr(calib.fields.yaml, "load", no_parse)
    with pytest.raises(CalibrationError) as err:
        load_rig(p)
    assert f"above the {MAX_CALIBRATION_BYTES} byte (1 MiB) limit" in str(err.value)
    assert err.value.path == str(p)


def test_load_rig_parses_each_file_once(tmp_path: Path, monkeypatch) -> None:
    (tmp_path / "camchain.yaml").write_text(CAMCHAIN)
    (tmp_path / "imu.yaml").write_text(IMU)
    parsed: list[str] = []
    real = yaml.load

    def counting(text: str, Loader: type) -> object:  # noqa: N803 - yaml's keyword
        parsed.append(text.split("\n", 1)[0])
        return real(text, Loader=Loader)

    monkeypatch.setattr(calib.fields.yaml, "load", counting)
    rig = load_rig(tmp_path / "camchain.yaml")
    assert rig.imu is not None and len(parsed) == 2  # camchain + the imu.yaml found beside it
    parsed.clear()
    load_rig(_euroc(tmp_path / "seq") / "mav0" / "cam0" / "sensor.yaml")
    assert len(parsed) == 2  # cam0 + imu0


def test_deep_nesting_is_refused_before_construction(tmp_path: Path) -> None:
    p = tmp_path / "x.yaml"
    p.write_text("a: " + "[" * 200_000 + "]" * 200_000)  # libyaml's composer segfaulted on this
    with pytest.raises(CalibrationError) as err:
        read_yaml(p)
    assert str(err.value) == f"{p}: YAML nested deeper than 32 levels; not a calibration file"


@pytest.mark.parametrize("text", ["t: 2021-13-45\n", "a: !!float xyz\n", "a: !!int 12x\n"])
def test_unconstructible_yaml_is_a_calibration_error(tmp_path: Path, text: str) -> None:
    p = tmp_path / "x.yaml"
    p.write_text(text)
    with pytest.raises(CalibrationError) as err:
        read_yaml(p)
    assert err.value.path == str(p)


def test_integer_too_large_for_a_float(tmp_path: Path) -> None:
    p = tmp_path / "camchain.yaml"
    p.write_text(CAMCHAIN.replace("458.654", "1" + "0" * 400))
    with pytest.raises(CalibrationError, match="not finite") as err:
        read_kalibr(p)
    assert err.value.key == "cam0.intrinsics"


@pytest.mark.parametrize("k1,ok", [("-1.0e+300", False), ("2.0e+4", False), ("-9000.0", True)])
def test_a_distortion_coefficient_no_lens_has_is_refused(tmp_path: Path, k1: str, ok: bool) -> None:
    """1e300 is finite but overflows the projection inside the filter's kernels (a traceback from numba)."""
    p = tmp_path / "camchain.yaml"
    text = CAMCHAIN.replace("-0.28340811", k1)
    assert text != CAMCHAIN
    p.write_text(text)
    if ok:
        read_kalibr(p)
        return
    with pytest.raises(CalibrationError, match="distortion coefficient 0 is .*a mangled number") as err:
        read_kalibr(p)
    assert (err.value.path, err.value.key) == (str(p), "cam0.distortion_coeffs")


@pytest.mark.parametrize(
    "intrinsics,ok",
    [
        ("[458.654, 457.296, 900.0, 248.375]", False),  # cx beyond the 752 px width
        ("[458.654, 457.296, 367.215, -3.0]", False),
        ("[458.654, 457.296, 248.375, 367.215]", True),  # swapped but still inside: cannot tell
        ("[458.654, 457.296, 751.5, 479.5]", True),  # the last pixel's centre edge is inside
        ("[458.654, 457.296, 751.6, 240.0]", False),
    ],
)
def test_principal_point_must_lie_in_the_image(tmp_path: Path, intrinsics: str, ok: bool) -> None:
    p = tmp_path / "camchain.yaml"
    p.write_text(CAMCHAIN.replace("[458.654, 457.296, 367.215, 248.375]", intrinsics))
    if ok:
        read_kalibr(p)
        return
    with pytest.raises(CalibrationError, match="principal point .* lies outside the 752x480 image") as err:
        read_kalibr(p)
    assert (err.value.path, err.value.key) == (str(p), "cam0.intrinsics")


def test_euroc_principal_point_outside_image(tmp_path: Path) -> None:
    folder = _euroc(tmp_path, cam=EUROC_CAM.replace("367.215, 248.375", "367.215, 600.0"))
    with pytest.raises(CalibrationError, match="outside the 752x480 image") as err:
        read_euroc_rig(folder)
    assert err.value.key == "intrinsics"


@pytest.mark.parametrize("key", ["gyroscope_noise_density", "accelerometer_random_walk"])
@pytest.mark.parametrize("value", ["0.0", "0", "-1.0e-3", ".nan", ".inf"])
def test_zero_negative_or_non_finite_imu_noise_is_refused(tmp_path: Path, key: str, value: str) -> None:
    lines = [f"  {key}: {value}" if line.startswith(f"  {key}:") else line for line in IMU.splitlines()]
    p = tmp_path / "imu.yaml"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(CalibrationError) as err:
        read_kalibr_imu(p)
    assert (err.value.path, err.value.key) == (str(p), f"imu0.{key}")
    folder = _euroc(tmp_path / "seq", imu=EUROC_IMU.replace(f"{key}: ", f"{key}: {value} #"))
    with pytest.raises(CalibrationError) as err:
        read_euroc_rig(folder)
    assert err.value.key == key and err.value.path.endswith("imu0/sensor.yaml")


def test_zero_noise_is_refused_in_memory_too() -> None:
    with pytest.raises(CalibrationError, match="must be positive, got 0.0") as err:
        ImuNoise(gyro_random_walk=0.0)
    assert err.value.key == "imu.gyro_random_walk"
    assert ImuNoise(gyro_random_walk=None).gyro_random_walk is None  # withheld stays withheld
