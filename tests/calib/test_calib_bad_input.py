"""Bad calibration files: each raises CalibrationError naming the file (.path) and the key (.key)."""

from __future__ import annotations

import copy
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml

from calib import PinholeRadtan, Rig, load_rig, read_euroc_rig, read_kalibr, write_kalibr
from calib.kalibr import read_kalibr_imu
from runtime.errors import CalibrationError

T_IMU_CAM = [
    [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975],
    [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768],
    [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949],
    [0.0, 0.0, 0.0, 1.0],
]
CAMCHAIN = {
    "cam0": {
        "T_imu_cam": T_IMU_CAM,
        "camera_model": "pinhole",
        "distortion_coeffs": [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05],
        "distortion_model": "radtan",
        "intrinsics": [458.654, 457.296, 367.215, 248.375],
        "resolution": [752, 480],
        "timeshift_cam_imu": 0.001,
    }
}
IMU = {
    "imu0": {
        "accelerometer_noise_density": 2.0e-3,
        "accelerometer_random_walk": 3.0e-3,
        "gyroscope_noise_density": 1.6968e-04,
        "gyroscope_random_walk": 1.9393e-05,
        "update_rate": 200.0,
    }
}
EUROC_CAM = {
    "sensor_type": "camera",
    "T_BS": {"cols": 4, "rows": 4, "data": [v for row in T_IMU_CAM for v in row]},
    "rate_hz": 20,
    "resolution": [752, 480],
    "camera_model": "pinhole",
    "intrinsics": [458.654, 457.296, 367.215, 248.375],
    "distortion_model": "radial-tangential",
    "distortion_coefficients": [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05],
}
EUROC_IMU = {
    "sensor_type": "imu",
    "T_BS": {"cols": 4, "rows": 4, "data": np.eye(4).ravel().tolist()},
    "rate_hz": 200,
    "gyroscope_noise_density": 1.6968e-04,
    "gyroscope_random_walk": 1.9393e-05,
    "accelerometer_noise_density": 2.0e-3,
    "accelerometer_random_walk": 3.0e-3,
}
NAN = float("nan")


def _write(path: Path, data: dict, header: bool = False) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(("%YAML:1.0\n" if header else "") + yaml.safe_dump(data, sort_keys=False))
    return path


def _set(data: dict, dotted: str, value: object) -> dict:
    out = copy.deepcopy(data)
    *parents, last = dotted.split(".")
    node = out
    for p in parents:
        node = node[p]
    if value is KeyError:
        del node[last]
    else:
        node[last] = value
    return out


def _raises(fn: Callable[[], object], path: Path, key: str | None) -> CalibrationError:
    with pytest.raises(CalibrationError) as err:
        fn()
    assert err.value.path == str(path)
    assert err.value.key == key
    assert str(path) in str(err.value) and (key is None or key in str(err.value))
    return err.value


def test_valid_fixtures_read(tmp_path: Path) -> None:
    """The unmodified fixtures are accepted, so each failure below is due to its one change."""
    rig = read_kalibr(_write(tmp_path / "c.yaml", CAMCHAIN, True), _write(tmp_path / "i.yaml", IMU, True))
    assert rig.is_complete is False and rig.missing() == ["camera_rate_hz"]
    assert rig.time_offset_s == 0.001
    mav0 = tmp_path / "seq" / "mav0"
    _write(mav0 / "cam0" / "sensor.yaml", EUROC_CAM, True)
    _write(mav0 / "imu0" / "sensor.yaml", EUROC_IMU, True)
    assert read_euroc_rig(tmp_path / "seq").isclose(rig.replace(time_offset_s=None, camera_rate_hz=20.0))
    _write(mav0 / "cam1" / "sensor.yaml", _set(EUROC_CAM, "intrinsics", [450.0, 451.0, 370.0, 250.0]), True)
    cam1 = read_euroc_rig(tmp_path / "seq", camera="cam1").camera
    assert cam1 is not None and (cam1.fx, cam1.cy) == (450.0, 250.0)
    _raises(lambda: read_euroc_rig(mav0, camera="cam2"), mav0, None)


def test_opencv_yaml_header_is_stripped_but_broken_yaml_is_reported(tmp_path: Path) -> None:
    p = _write(tmp_path / "c.yaml", CAMCHAIN, header=True)
    with pytest.raises(yaml.YAMLError):  # the premise: PyYAML alone rejects the header
        yaml.safe_load(p.read_text())
    assert read_kalibr(p).camera is not None
    bad = tmp_path / "broken.yaml"
    bad.write_text("%YAML:1.0\ncam0:\n  intrinsics: [1, 2\n  resolution: [3, 4]\n")
    err = _raises(lambda: read_kalibr(bad), bad, None)
    assert "invalid YAML at line" in str(err)
    scalar = tmp_path / "scalar.yaml"
    scalar.write_text("%YAML:1.0\n42\n")
    _raises(lambda: read_kalibr(scalar), scalar, None)


def test_missing_files(tmp_path: Path) -> None:
    _raises(lambda: read_kalibr(tmp_path / "nope.yaml"), tmp_path / "nope.yaml", None)
    cam = _write(tmp_path / "c.yaml", CAMCHAIN)
    _raises(lambda: read_kalibr(cam, tmp_path / "imu.yaml"), tmp_path / "imu.yaml", None)
    _raises(lambda: read_euroc_rig(tmp_path / "no_sequence"), tmp_path / "no_sequence", None)
    (tmp_path / "empty").mkdir()
    _raises(lambda: read_euroc_rig(tmp_path / "empty"), tmp_path / "empty", None)
    _raises(lambda: load_rig(tmp_path / "nope.yaml"), tmp_path / "nope.yaml", None)
    mav0 = tmp_path / "seq" / "mav0"
    _write(mav0 / "cam0" / "sensor.yaml", EUROC_CAM, True)
    assert read_euroc_rig(tmp_path / "seq").imu is None          # imu0/sensor.yaml absent: withheld
    (mav0 / "imu0" / "sensor.yaml").mkdir(parents=True)         # a folder is not withheld calibration
    err = _raises(lambda: read_euroc_rig(tmp_path / "seq"), mav0 / "imu0" / "sensor.yaml", None)
    assert "is a folder" in str(err)


KALIBR_CASES = [
    ("missing camera block", "cam0", KeyError, "cam0"),
    ("missing intrinsics", "cam0.intrinsics", KeyError, "cam0.intrinsics"),
    ("missing resolution", "cam0.resolution", KeyError, "cam0.resolution"),
    ("missing distortion", "cam0.distortion_coeffs", KeyError, "cam0.distortion_coeffs"),
    ("missing distortion model", "cam0.distortion_model", KeyError, "cam0.distortion_model"),
    ("unknown distortion model", "cam0.distortion_model", "fov", "cam0.distortion_model"),
    ("unknown camera model", "cam0.camera_model", "omni", "cam0.camera_model"),
    ("NaN intrinsics", "cam0.intrinsics", [NAN, 457.0, 367.0, 248.0], "cam0.intrinsics"),
    ("string intrinsics", "cam0.intrinsics", ["458", 457.0, 367.0, 248.0], "cam0.intrinsics"),
    ("three intrinsics", "cam0.intrinsics", [458.0, 457.0, 367.0], "cam0.intrinsics"),
    ("negative focal length", "cam0.intrinsics", [-458.0, 457.0, 367.0, 248.0], "cam0.intrinsics"),
    ("float resolution", "cam0.resolution", [752.0, 480], "cam0.resolution"),
    ("zero resolution", "cam0.resolution", [0, 480], "cam0.resolution"),
    ("short distortion", "cam0.distortion_coeffs", [0.1, 0.2, 0.3], "cam0.distortion_coeffs"),
    ("equidistant with 5 coeffs", "cam0.distortion_model", "equidistant", "cam0.distortion_coeffs"),
    ("NaN distortion", "cam0.distortion_coeffs", [NAN, 0.0, 0.0, 0.0], "cam0.distortion_coeffs"),
    ("3x4 extrinsics", "cam0.T_imu_cam", T_IMU_CAM[:3], "cam0.T_imu_cam"),
    ("ragged extrinsics", "cam0.T_imu_cam", [r[:3] for r in T_IMU_CAM], "cam0.T_imu_cam"),
    ("scaled rotation", "cam0.T_imu_cam", (np.diag([1.1, 1, 1, 1]) @ T_IMU_CAM).tolist(), "cam0.T_imu_cam"),
    ("reflection", "cam0.T_imu_cam", (np.diag([-1.0, 1, 1, 1]) @ T_IMU_CAM).tolist(), "cam0.T_imu_cam"),
    ("bad last row", "cam0.T_imu_cam", [*T_IMU_CAM[:3], [0, 0, 1, 1]], "cam0.T_imu_cam"),
    ("NaN extrinsics", "cam0.T_imu_cam", [[NAN] * 4, *T_IMU_CAM[1:]], "cam0.T_imu_cam"),
    ("string timeshift", "cam0.timeshift_cam_imu", "0.001", "cam0.timeshift_cam_imu"),
    ("NaN timeshift", "cam0.timeshift_cam_imu", NAN, "cam0.timeshift_cam_imu"),
    ("focal length in the wrong unit", "cam0.intrinsics", [1e9, 1e9, 367.0, 248.0], "cam0.intrinsics"),
    ("tiny focal length", "cam0.intrinsics", [0.001, 0.001, 367.0, 248.0], "cam0.intrinsics"),
    ("lever arm in millimetres", "cam0.T_imu_cam",
     [[*r[:3], 1000 * r[3]] for r in T_IMU_CAM[:3]] + [T_IMU_CAM[3]], "cam0.T_imu_cam"),
]


@pytest.mark.parametrize("what,dotted,value,key", KALIBR_CASES, ids=[c[0] for c in KALIBR_CASES])
def test_bad_kalibr_camchain(tmp_path: Path, what: str, dotted: str, value: object, key: str) -> None:
    data = CAMCHAIN
    if what == "equidistant with 5 coeffs":
        data = _set(data, "cam0.distortion_coeffs", [0.1, 0.0, 0.0, 0.0, 0.0])
    p = _write(tmp_path / "camchain.yaml", _set(data, dotted, value), header=True)
    _raises(lambda: read_kalibr(p), p, key)


def test_inconsistent_extrinsics_keys(tmp_path: Path) -> None:
    T_cam_imu = np.linalg.inv(np.array(T_IMU_CAM))
    good = _write(tmp_path / "good.yaml", _set(CAMCHAIN, "cam0.T_cam_imu", T_cam_imu.tolist()))
    assert read_kalibr(good).T_IC is not None
    shifted = T_cam_imu.copy()
    shifted[0, 3] += 0.01
    p = _write(tmp_path / "bad.yaml", _set(CAMCHAIN, "cam0.T_cam_imu", shifted.tolist()))
    _raises(lambda: read_kalibr(p), p, "cam0.T_imu_cam")


@pytest.mark.parametrize("typo,meant", [("T_cam_imuu", "T_cam_imu"), ("T_imu_camera", "T_imu_cam"),
                                        ("timeshift_cam_imuu", "timeshift_cam_imu")])
def test_a_misspelt_key_is_not_withheld_calibration(tmp_path: Path, typo: str, meant: str) -> None:
    data = _set(_set(CAMCHAIN, "cam0.T_imu_cam", KeyError), "cam0.timeshift_cam_imu", KeyError)
    p = _write(tmp_path / "c.yaml", _set(data, f"cam0.{typo}", CAMCHAIN["cam0"]["T_imu_cam"]))
    err = _raises(lambda: read_kalibr(p), p, f"cam0.{typo}")
    assert f"did you mean '{meant}'" in str(err)
    for foreign in ("label", "ros_topic", "cam_overlap", "T_cn_cnm2", "T_cam_imu_gt", "intrinsics_cov"):
        other = _write(tmp_path / f"{foreign}.yaml", _set(data, f"cam0.{foreign}", "x"))   # ignored
        assert read_kalibr(other).T_IC is None


@pytest.mark.parametrize("shift", [5.0, -1.5, 1e5])
def test_an_implausible_time_offset_names_the_key(tmp_path: Path, shift: float) -> None:
    p = _write(tmp_path / "c.yaml", _set(CAMCHAIN, "cam0.timeshift_cam_imu", shift))
    err = _raises(lambda: read_kalibr(p), p, "cam0.timeshift_cam_imu")
    assert "implausible for a camera-IMU time offset" in str(err)
    assert read_kalibr(_write(tmp_path / "ok.yaml", _set(CAMCHAIN, "cam0.timeshift_cam_imu", -1.0))) \
        .time_offset_s == -1.0


def test_withheld_values_are_none_not_defaults(tmp_path: Path) -> None:
    data = _set(_set(CAMCHAIN, "cam0.T_imu_cam", KeyError), "cam0.timeshift_cam_imu", KeyError)
    imu = _set(IMU, "imu0.gyroscope_random_walk", None)
    rig = read_kalibr(_write(tmp_path / "c.yaml", data), _write(tmp_path / "i.yaml", imu))
    assert rig.T_IC is None and rig.time_offset_s is None and rig.imu is not None
    assert rig.imu.gyro_random_walk is None and rig.imu.gyro_noise_density == 1.6968e-04
    assert rig.missing() == ["T_IC", "time_offset_s", "camera_rate_hz", "imu.gyro_random_walk"]
    no_camera = _write(tmp_path / "n.yaml", _set(CAMCHAIN, "cam0.intrinsics", None))
    assert read_kalibr(no_camera).camera is None


IMU_CASES = [
    ("missing imu block", "imu0", KeyError, "imu0"),
    ("missing gyro noise", "imu0.gyroscope_noise_density", KeyError, "imu0.gyroscope_noise_density"),
    ("missing rate", "imu0.update_rate", KeyError, "imu0.update_rate"),
    ("NaN accel noise", "imu0.accelerometer_noise_density", NAN, "imu0.accelerometer_noise_density"),
    ("negative accel walk", "imu0.accelerometer_random_walk", -1e-3, "imu0.accelerometer_random_walk"),
    ("zero rate", "imu0.update_rate", 0.0, "imu0.update_rate"),
    ("text noise", "imu0.gyroscope_random_walk", "small", "imu0.gyroscope_random_walk"),
]


@pytest.mark.parametrize("what,dotted,value,key", IMU_CASES, ids=[c[0] for c in IMU_CASES])
def test_bad_kalibr_imu(tmp_path: Path, what: str, dotted: str, value: object, key: str) -> None:
    cam = _write(tmp_path / "camchain.yaml", CAMCHAIN)
    p = _write(tmp_path / "imu.yaml", _set(IMU, dotted, value), header=True)
    _raises(lambda: read_kalibr(cam, p), p, key)


EUROC_CASES = [
    ("cam", "missing intrinsics", "intrinsics", KeyError, "intrinsics"),
    ("cam", "missing distortion", "distortion_coefficients", KeyError, "distortion_coefficients"),
    ("cam", "missing T_BS", "T_BS", KeyError, "T_BS"),
    ("cam", "T_BS with 15 entries", "T_BS.data", [0.0] * 15, "T_BS.data"),
    ("cam", "T_BS 3 rows", "T_BS.rows", 3, "T_BS"),
    (
        "cam",
        "T_BS not orthonormal",
        "T_BS.data",
        [2.0, *([0.0] * 4), 1.0, *([0.0] * 4), 1, 0, 0, 0, 0, 1],
        "T_BS",
    ),
    ("cam", "T_BS NaN", "T_BS.data", [NAN] + [0.0] * 15, "T_BS.data"),
    ("cam", "unknown distortion model", "distortion_model", "fov", "distortion_model"),
    ("cam", "imu file as camera", "sensor_type", "imu", "sensor_type"),
    ("cam", "negative rate", "rate_hz", -20, "rate_hz"),
    ("imu", "missing gyro noise", "gyroscope_noise_density", KeyError, "gyroscope_noise_density"),
    ("imu", "NaN accel noise", "accelerometer_noise_density", NAN, "accelerometer_noise_density"),
    ("imu", "negative accel walk", "accelerometer_random_walk", -1.0, "accelerometer_random_walk"),
    ("imu", "imu T_BS reflection", "T_BS.data", np.diag([1.0, 1, -1, 1]).ravel().tolist(), "T_BS"),
    # 1e300 is finite and positive, but its square overflowed the filter's preintegration mid-run
    ("imu", "gyro noise 1e300", "gyroscope_noise_density", 1e300, "gyroscope_noise_density"),
    ("imu", "accel walk in the wrong unit", "accelerometer_random_walk", 3000.0, "accelerometer_random_walk"),
    ("imu", "imu rate 1e300", "rate_hz", 1e300, "rate_hz"),
    ("cam", "camera rate 1e300", "rate_hz", 1e300, "rate_hz"),
]


@pytest.mark.parametrize("which,what,dotted,value,key", EUROC_CASES, ids=[c[1] for c in EUROC_CASES])
def test_bad_euroc_files(tmp_path: Path, which: str, what: str, dotted: str, value: object, key: str) -> None:
    mav0 = tmp_path / "seq" / "mav0"
    cam = _set(EUROC_CAM, dotted, value) if which == "cam" else EUROC_CAM
    imu = _set(EUROC_IMU, dotted, value) if which == "imu" else EUROC_IMU
    cam_path = _write(mav0 / "cam0" / "sensor.yaml", cam, header=True)
    imu_path = _write(mav0 / "imu0" / "sensor.yaml", imu, header=True)
    _raises(lambda: read_euroc_rig(tmp_path / "seq"), cam_path if which == "cam" else imu_path, key)


def test_load_rig_rejects_unknown_yaml(tmp_path: Path) -> None:
    p = _write(tmp_path / "other.yaml", {"camera": {"fx": 1.0}})
    _raises(lambda: load_rig(p), p, "cam0")


def test_writer_refuses_what_kalibr_cannot_hold(tmp_path: Path) -> None:
    cam = PinholeRadtan(640, 480, 500.0, 500.0, 320.0, 240.0, [0.1, 0.01, 0.0, 0.0, 0.001])
    target = tmp_path / "c.yaml"
    _raises(lambda: write_kalibr(Rig(cam), target), target, "cam0.distortion_coeffs")
    assert not target.exists()
    zero_k3 = PinholeRadtan(640, 480, 500.0, 500.0, 320.0, 240.0, [0.1, 0.01, 0.0, 0.0, 0.0])
    write_kalibr(Rig(zero_k3), target)
    back = read_kalibr(target).camera
    assert back is not None and back.distortion.tolist() == [0.1, 0.01, 0.0, 0.0]


def test_yaml_12_numbers_without_a_point_and_duplicate_keys(tmp_path: Path) -> None:
    """`2e-5` is a number in YAML 1.2 (PyYAML's 1.1 reads it as text); a key given twice is refused."""
    imu = tmp_path / "imu.yaml"
    imu.write_text("imu0:\n  accelerometer_noise_density: 2e-3\n  accelerometer_random_walk: 3.0e-3\n"
                   "  gyroscope_noise_density: 1.6968e-04\n  gyroscope_random_walk: 2e-5\n"
                   "  update_rate: 2e2\n")
    noise = read_kalibr_imu(imu)
    assert noise.gyro_random_walk == 2e-5 and noise.accel_noise_density == 2e-3 and noise.rate_hz == 200.0
    cam = tmp_path / "c.yaml"
    cam.write_text(yaml.safe_dump(CAMCHAIN, sort_keys=False) + "  timeshift_cam_imu: 0.002\n")
    err = _raises(lambda: read_kalibr(cam), cam, None)
    assert "key 'timeshift_cam_imu' given twice" in str(err)
