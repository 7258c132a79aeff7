"""Rig and ImuNoise: validation of T_IC and numbers, withheld fields, require()."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib import ImuNoise, PinholeRadtan, Rig
from calib.rig import invert_rigid, rigid_transform
from runtime.errors import CalibrationError

CAM = PinholeRadtan(752, 480, 458.654, 457.296, 367.215, 248.375, [-0.28, 0.07, 0.0002, 0.00002])
IMU = ImuNoise(1.6968e-4, 1.9393e-5, 2.0e-3, 3.0e-3, 200.0)


def _pose(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=seed).as_matrix()
    T[:3, 3] = rng.normal(size=3)
    return T


def test_full_rig_properties() -> None:
    T = _pose(0)
    rig = Rig(CAM, T, 0.002, IMU, 20.0, "test")
    assert rig.missing() == [] and rig.is_complete
    np.testing.assert_array_equal(rig.R_IC, T[:3, :3])
    np.testing.assert_array_equal(rig.p_IC, T[:3, 3])
    np.testing.assert_allclose(rig.T_CI @ T, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(rig.T_CI, np.linalg.inv(T), atol=1e-12)
    rig.require("camera", "T_IC", "imu", "time_offset_s")
    with pytest.raises(ValueError):
        rig.T_IC[0, 0] = 2.0  # stored read-only
    assert rig.isclose(Rig(CAM, T.copy(), 0.002, IMU, 20.0, "other name"))
    assert not rig.isclose(rig.replace(time_offset_s=0.003))
    assert not rig.isclose(rig.replace(imu=None))


def test_withheld_fields_are_listed_and_required() -> None:
    rig = Rig(CAM, None, None, ImuNoise(gyro_noise_density=1e-4, rate_hz=200.0), None, "bring-up")
    assert rig.missing() == [
        "T_IC",
        "time_offset_s",
        "camera_rate_hz",
        "imu.gyro_random_walk",
        "imu.accel_noise_density",
        "imu.accel_random_walk",
    ]
    rig.require("camera", "imu.gyro_noise_density")
    with pytest.raises(CalibrationError) as err:
        rig.require("camera", "T_IC", "imu")
    assert err.value.key == "T_IC"
    assert "imu.accel_random_walk" in str(err.value) and "imu.gyro_noise_density" not in str(err.value)
    with pytest.raises(CalibrationError):
        _ = rig.R_IC
    with pytest.raises(ValueError):
        rig.require("intrinsics")
    empty = Rig()
    assert empty.missing()[:4] == ["camera", "T_IC", "time_offset_s", "camera_rate_hz"]
    assert len(empty.missing()) == 9


@pytest.mark.parametrize(
    "mutate,fragment",
    [
        (lambda T: T[:3], "4x4"),
        (lambda T: np.where(np.eye(4) > 0, np.nan, T), "non-finite"),
        (lambda T: T @ np.diag([1.0, 1.0, 1.01, 1.0]), "orthonormal"),
        (lambda T: T @ np.diag([1.0, 1.0, -1.0, 1.0]), "reflection"),
        (lambda T: np.vstack([T[:3], [[0.0, 0.0, 0.1, 1.0]]]), "last row"),
        (lambda T: [["a"] * 4] * 4, "numeric"),
    ],
)
def test_bad_extrinsics_raise(mutate, fragment: str) -> None:
    with pytest.raises(CalibrationError) as err:
        Rig(CAM, mutate(_pose(1)))
    assert err.value.key == "T_IC"
    assert fragment in str(err.value)


def test_rigid_transform_accepts_small_rounding_and_inverts() -> None:
    T = _pose(2)
    T_rounded = np.round(T, 6)  # as printed with 6 decimals
    M = rigid_transform(T_rounded, "x")
    assert not M.flags.writeable
    np.testing.assert_allclose(invert_rigid(M) @ M, np.eye(4), atol=1e-5)


@pytest.mark.parametrize(
    "kwargs,key",
    [
        ({"time_offset_s": float("nan")}, "time_offset_s"),
        ({"camera_rate_hz": 0.0}, "camera_rate_hz"),
        ({"camera_rate_hz": "20"}, "camera_rate_hz"),
        ({"camera": "cam0"}, "camera"),
    ],
)
def test_bad_rig_numbers_raise(kwargs: dict, key: str) -> None:
    with pytest.raises(CalibrationError) as err:
        Rig(**kwargs)
    assert err.value.key == key


@pytest.mark.parametrize(
    "kwargs,key",
    [
        ({"gyro_noise_density": -1e-4}, "imu.gyro_noise_density"),
        ({"accel_random_walk": float("inf")}, "imu.accel_random_walk"),
        ({"rate_hz": 0.0}, "imu.rate_hz"),
        ({"accel_noise_density": True}, "imu.accel_noise_density"),
    ],
)
def test_bad_imu_noise_raises(kwargs: dict, key: str) -> None:
    with pytest.raises(CalibrationError) as err:
        ImuNoise(**kwargs)
    assert err.value.key == key
