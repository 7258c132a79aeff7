"""Property tests of the calibration readers: any bytes give a Rig or a CalibrationError, never another
exception; rigs written by write_kalibr read back unchanged.

Inputs: arbitrary bytes, and valid Kalibr camchain / imu, OpenVINS and EuRoC sensor.yaml files with a few
edits (values replaced by wrong types, impossible numbers or YAML syntax; bytes changed; spans deleted,
duplicated or cut).
"""
from __future__ import annotations

import os
import re
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from calib import ImuNoise, Pinhole, PinholeEquidistant, PinholeRadtan, Rig, load_rig, write_kalibr
from calib.kalibr import read_kalibr, read_kalibr_imu
from calib.rig import ImuNoise as _ImuNoise
from runtime.errors import CalibrationError
from tests.calib.test_calib_limits import EUROC_CAM, EUROC_IMU

RIGS = resources.files("calib") / "rigs"
CAMCHAIN = (RIGS / "euroc_camchain.yaml").read_bytes()
IMU = (RIGS / "euroc_imu.yaml").read_bytes()
#: OpenVINS flavour: T_imu_cam (= T_IC) instead of Kalibr's T_cam_imu, %YAML:1.0 header.
OPENVINS = b"""%YAML:1.0
cam0:
  T_imu_cam:
    - [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975]
    - [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768]
    - [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949]
    - [0.0, 0.0, 0.0, 1.0]
  camera_model: pinhole
  distortion_coeffs: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
  distortion_model: radtan
  intrinsics: [458.654, 457.296, 367.215, 248.375]
  resolution: [752, 480]
  timeshift_cam_imu: 0.0
"""
VALID = {"camchain": CAMCHAIN, "imu": IMU, "openvins": OPENVINS,
         "euroc_cam": EUROC_CAM.encode(), "euroc_imu": EUROC_IMU.encode()}
#: Deterministic in CI; DAVIO_FUZZ_EXAMPLES=5000 (and a random seed) for a longer local campaign.
FUZZ = settings(max_examples=int(os.environ.get("DAVIO_FUZZ_EXAMPLES", 60)), deadline=None,
                derandomize="DAVIO_FUZZ_EXAMPLES" not in os.environ, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture])


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("calib_fuzz")


#: Tokens written over a value of a valid file: wrong types, impossible numbers, YAML syntax.
TOKENS = [b"0", b"-1", b"0.0", b"-0.0", b"null", b"~", b"1e999", b".nan", b"-.inf", b"1" + b"0" * 400,
          b"true", b"[1, 2]", b"{}", b"[]", b"abc", b"caf\xe9", b"'3'", b"!!float", b"&a", b"*a", b"[", b"{",
          b":", b"- ", b"\n  ", b"\t", b"2021-13-45", b"equidistant", b"fisheye", b"none",
          b"[1e400, 0, 0, 0]"]
_TOKEN_RE = re.compile(rb"[-+]?[0-9][0-9.e+-]*|[A-Za-z_]+")


@st.composite
def mutated(draw: st.DrawFn, valid: bytes) -> bytes:
    """`valid` with 1-3 edits: mostly a number or word replaced by a TOKENS entry; sometimes a printable
    byte changed, a span deleted or duplicated, or the file truncated."""
    data = bytes(valid)
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["token"] * 6 + ["byte", "delete", "duplicate", "truncate"]))
        i = draw(st.integers(0, max(len(data) - 1, 0)))
        if op == "token":
            spans = [m.span() for m in _TOKEN_RE.finditer(data)]
            if spans:
                a, b = draw(st.sampled_from(spans))
                data = data[:a] + draw(st.sampled_from(TOKENS)) + data[b:]
        elif op == "byte":
            data = data[:i] + bytes([draw(st.sampled_from(list(range(32, 127)) + [10, 0xE9]))]) + data[i + 1:]
        elif op == "delete":
            data = data[:i] + data[i + draw(st.integers(1, 16)):]
        elif op == "duplicate":
            j = draw(st.integers(i, len(data)))
            data = data[:j] + data[i:j] + data[j:]
        else:
            data = data[:i]
    return data


def _read(kind: str, path: Path) -> object:
    if kind == "imu":
        return read_kalibr_imu(path)
    if kind.startswith("euroc"):
        return load_rig(path.parent.parent) if kind == "euroc_imu" else load_rig(path)
    return read_kalibr(path)


def _path(folder: Path, kind: str) -> Path:
    if kind.startswith("euroc"):
        mav0 = folder / "mav0"
        for name, text in (("cam0", EUROC_CAM), ("imu0", EUROC_IMU)):
            (mav0 / name).mkdir(parents=True, exist_ok=True)
            (mav0 / name / "sensor.yaml").write_text(text)
        return mav0 / ("cam0" if kind == "euroc_cam" else "imu0") / "sensor.yaml"
    return folder / f"{kind}.yaml"


@pytest.mark.parametrize("kind", sorted(VALID))
def test_valid_files_read(folder: Path, kind: str) -> None:
    path = _path(folder, kind)
    path.write_bytes(VALID[kind])
    assert isinstance(_read(kind, path), (Rig, ImuNoise))


@pytest.mark.parametrize("kind", sorted(VALID))
@FUZZ
@given(data=st.data())
def test_mutated_files_read_or_raise_calibration_error(folder: Path, kind: str, data: st.DataObject) -> None:
    path = _path(folder, kind)
    path.write_bytes(data.draw(mutated(VALID[kind])))
    try:
        out = _read(kind, path)
    except CalibrationError as exc:
        assert str(exc)  # a message, naming the file
    else:
        assert isinstance(out, (Rig, ImuNoise))


@FUZZ
@given(raw=st.binary(max_size=400) | st.text(max_size=300).map(str.encode))
def test_arbitrary_bytes_read_or_raise_calibration_error(folder: Path, raw: bytes) -> None:
    path = folder / "arbitrary.yaml"
    path.write_bytes(raw)
    try:
        load_rig(path)
    except CalibrationError:
        pass


_finite = st.floats(-0.3, 0.3, allow_nan=False)
_positive = st.floats(1e-6, 10.0, allow_nan=False)


@st.composite
def rigs(draw: st.DrawFn) -> Rig:
    w, h = draw(st.integers(16, 2000)), draw(st.integers(16, 2000))
    f = draw(st.floats(0.2, 20.0)) * w          # focal lengths of real lenses for this width (FOCAL_RANGE)
    cx, cy = draw(st.floats(-0.5, w - 0.5)), draw(st.floats(-0.5, h - 0.5))
    cls = draw(st.sampled_from([Pinhole, PinholeRadtan, PinholeEquidistant]))
    n = {Pinhole: 0, PinholeRadtan: 4, PinholeEquidistant: 4}[cls]
    fy = draw(st.floats(0.2, 20.0)) * h
    cam = cls(w, h, f, fy, cx, cy, draw(st.lists(_finite, min_size=n, max_size=n)))
    q = np.array(draw(st.lists(st.floats(-1, 1), min_size=4, max_size=4))) + [0.0, 0.0, 0.0, 1.5]
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(q / np.linalg.norm(q)).as_matrix()
    T[:3, 3] = draw(st.lists(_finite, min_size=3, max_size=3))
    imu = _ImuNoise(*[draw(st.none() | _positive) for _ in range(5)])
    return Rig(cam, draw(st.none() | st.just(T)), draw(st.none() | _finite), imu,
               draw(st.none() | _positive), draw(st.text("abcxyz_-0123", min_size=1, max_size=12)))


@FUZZ
@given(rig=rigs(), key=st.sampled_from(["T_cam_imu", "T_imu_cam"]))
def test_written_rigs_read_back(folder: Path, rig: Rig, key: str) -> None:
    camchain, imu = folder / "rt_camchain.yaml", folder / "rt_imu.yaml"
    write_kalibr(rig, camchain, imu, extrinsics_key=key, comment="fuzz round trip: é")
    back = read_kalibr(camchain, imu)
    assert back.isclose(rig, rtol=1e-12, atol=1e-12), (back, rig)
