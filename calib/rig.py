"""The camera–IMU rig: camera model, extrinsics T_IC, time offset, IMU noise; each may be withheld.

A withheld (unknown) value is None, never a silent default: consumers call :meth:`Rig.require`
for what they cannot work without, and :meth:`Rig.missing` lists what an estimator must calibrate
online. Validation errors are :class:`CalibrationError` whose ``key`` names the field
(``T_IC``, ``time_offset_s``, ``camera_rate_hz``, ``imu.<field>``); readers re-key them to their
file's own keys.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from calib.camera import CameraModel
from runtime.errors import CalibrationError

#: Tolerance on |R^T R - I| (max abs entry) and on the last row of a rigid transform: accepts
#: rotations printed with 6 decimals (Kalibr and EuRoC files carry 9 to 12).
RIGID_TOLERANCE = 1e-5

IMU_FIELDS = ("gyro_noise_density", "gyro_random_walk", "accel_noise_density", "accel_random_walk", "rate_hz")
MAX_TIME_OFFSET_S = 1.0
"""Largest camera-IMU time offset a rig may hold (s): Kalibr's are milliseconds; a larger one is a unit
error or two unsynchronised clocks, which the filter's online time-offset estimate cannot absorb."""
MAX_LEVER_ARM_M = 5.0
"""Largest camera-IMU distance accepted, m: a translation in mm or cm reads as tens of metres or more."""
MAX_NOISE = 100.0
"""Largest IMU noise density or random walk accepted (SI units): datasheet values are 1e-6 to 1e-1; a
larger one is a unit error (deg for rad, mg for m/s^2, variance for density) and from about 1e154 its
square overflows the filter."""
MAX_IMU_RATE_HZ = 1e5
"""Highest IMU sample rate accepted, Hz (IMUs sample at up to a few kHz)."""
MAX_CAMERA_RATE_HZ = 1e4
"""Highest camera frame rate accepted, Hz."""
RIG_FIELDS = ("camera", "T_IC", "time_offset_s", "camera_rate_hz") + tuple(f"imu.{f}" for f in IMU_FIELDS)


def _optional_number(value: object, key: str, positive: bool = False, hint: str = "",
                     maximum: float | None = None) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise CalibrationError(f"expected a number, got {value!r}", None, key)
    f = float(value)
    if not math.isfinite(f):
        raise CalibrationError(f"must be finite, got {f}", None, key)
    if positive and f <= 0.0:
        raise CalibrationError(f"must be positive, got {f}{hint}", None, key)
    if maximum is not None and f > maximum:
        raise CalibrationError(f"{f:g} is implausible (above {maximum:g}){hint}", None, key)
    return f


def rigid_problem(T: object, tolerance: float = RIGID_TOLERANCE) -> str | None:
    """Why `T` is not a 4x4 rigid transform (shape, finiteness, last row (0, 0, 0, 1), orthonormal rotation
    within `tolerance`, det(R) = +1), or None when it is one."""
    try:
        M = np.array(T, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:
        return f"not a numeric 4x4 matrix ({exc})"
    if M.shape != (4, 4):
        return f"must be a 4x4 matrix, got shape {M.shape}"
    if not np.all(np.isfinite(M)):
        return "contains non-finite numbers"
    if np.max(np.abs(M[3] - np.array([0.0, 0.0, 0.0, 1.0]))) > tolerance:
        return f"last row must be [0, 0, 0, 1], got {M[3].tolist()}"
    R = M[:3, :3]
    err = float(np.max(np.abs(R.T @ R - np.eye(3))))
    if err > tolerance:
        return f"rotation part is not orthonormal (max |R^T R - I| = {err:.3g})"
    det = float(np.linalg.det(R))
    if det < 0.0:
        return f"rotation part is a reflection (det = {det:.6f})"
    return None


def rigid_transform(T: object, key: str = "T_IC", tolerance: float = RIGID_TOLERANCE) -> np.ndarray:
    """Validate a 4x4 rigid transform (`rigid_problem`) and return it as a read-only float64 array; raises
    CalibrationError(key=key) when it is not one."""
    problem = rigid_problem(T, tolerance)
    if problem is not None:
        raise CalibrationError(problem, None, key)
    M = np.array(T, dtype=np.float64)
    M[3] = (0.0, 0.0, 0.0, 1.0)
    M.setflags(write=False)
    return M


def invert_rigid(T: np.ndarray) -> np.ndarray:
    """Inverse of a 4x4 rigid transform (R^T, -R^T p)."""
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


_IMU_HINT = " (give the IMU's datasheet or Allan-variance value, or null to withhold it)"


@dataclass(frozen=True)
class ImuNoise:
    """Continuous-time IMU noise model (Kalibr / EuRoC convention); None = withheld.

    Every given value must be finite and positive: a zero noise density or random walk would make the
    filter trust the IMU without limit, so it is refused (CalibrationError), never replaced.

    Attributes:
        gyro_noise_density: rad/s/sqrt(Hz).
        gyro_random_walk: rad/s^2/sqrt(Hz) (gyro bias diffusion).
        accel_noise_density: m/s^2/sqrt(Hz).
        accel_random_walk: m/s^3/sqrt(Hz) (accel bias diffusion).
        rate_hz: nominal IMU sample rate, Hz.
    """

    gyro_noise_density: float | None = None
    gyro_random_walk: float | None = None
    accel_noise_density: float | None = None
    accel_random_walk: float | None = None
    rate_hz: float | None = None

    def __post_init__(self) -> None:
        for name in IMU_FIELDS:
            value = _optional_number(getattr(self, name), f"imu.{name}", positive=True, hint=_IMU_HINT,
                                     maximum=MAX_IMU_RATE_HZ if name == "rate_hz" else MAX_NOISE)
            object.__setattr__(self, name, value)

    def missing(self) -> list[str]:
        """Names (``imu.<field>``) of the withheld fields."""
        return [f"imu.{name}" for name in IMU_FIELDS if getattr(self, name) is None]


@dataclass(frozen=True, eq=False)
class Rig:
    """Monocular camera + IMU calibration (body frame = IMU frame I).

    Attributes:
        camera: camera model with intrinsics and distortion, or None (withheld).
        T_IC: 4x4 pose of the camera in the IMU frame (x_I = T_IC x_C), or None (withheld).
        time_offset_s: camera-to-IMU clock offset in seconds, t_imu = t_cam + time_offset_s
            (Kalibr ``timeshift_cam_imu``), or None (withheld).
        imu: IMU noise model, or None (all of it withheld).
        camera_rate_hz: nominal camera frame rate, Hz, or None.
        name: free-form rig name (file or dataset it came from).
    """

    camera: CameraModel | None = None
    T_IC: np.ndarray | None = None
    time_offset_s: float | None = None
    imu: ImuNoise | None = None
    camera_rate_hz: float | None = None
    name: str = ""

    def __post_init__(self) -> None:
        if self.camera is not None and not isinstance(self.camera, CameraModel):
            raise CalibrationError(
                f"expected a CameraModel, got {type(self.camera).__name__}", None, "camera"
            )
        if self.imu is not None and not isinstance(self.imu, ImuNoise):
            raise CalibrationError(f"expected an ImuNoise, got {type(self.imu).__name__}", None, "imu")
        if self.T_IC is not None:
            object.__setattr__(self, "T_IC", rigid_transform(self.T_IC, "T_IC"))
            lever = float(np.linalg.norm(self.T_IC[:3, 3]))
            if lever > MAX_LEVER_ARM_M:
                raise CalibrationError(
                    f"the camera-IMU lever arm is {lever:.4g} m, implausible (more than "
                    f"{MAX_LEVER_ARM_M:g} m): the translation must be in metres, not millimetres or "
                    "centimetres", None, "T_IC")
        object.__setattr__(self, "time_offset_s", _optional_number(self.time_offset_s, "time_offset_s"))
        if self.time_offset_s is not None and abs(self.time_offset_s) > MAX_TIME_OFFSET_S:
            raise CalibrationError(
                f"{self.time_offset_s:g} s is implausible for a camera-IMU time offset (more than "
                f"{MAX_TIME_OFFSET_S:g} s; it is in seconds, not milliseconds); a larger offset between two "
                "clocks must be removed from the stamps", None, "time_offset_s")
        object.__setattr__(
            self, "camera_rate_hz", _optional_number(self.camera_rate_hz, "camera_rate_hz", positive=True,
                                                     maximum=MAX_CAMERA_RATE_HZ)
        )
        object.__setattr__(self, "name", str(self.name))

    @property
    def R_IC(self) -> np.ndarray:
        """3x3 rotation camera -> IMU; CalibrationError if T_IC is withheld."""
        self.require("T_IC")
        assert self.T_IC is not None
        return self.T_IC[:3, :3]

    @property
    def p_IC(self) -> np.ndarray:
        """Camera centre in the IMU frame (m); CalibrationError if T_IC is withheld."""
        self.require("T_IC")
        assert self.T_IC is not None
        return self.T_IC[:3, 3]

    @property
    def T_CI(self) -> np.ndarray:
        """4x4 pose of the IMU in the camera frame (inverse of T_IC); CalibrationError if withheld."""
        self.require("T_IC")
        assert self.T_IC is not None
        return invert_rigid(self.T_IC)

    def missing(self) -> list[str]:
        """Names of the withheld fields, in RIG_FIELDS order (IMU ones as ``imu.<field>``)."""
        out = [
            name
            for name in ("camera", "T_IC", "time_offset_s", "camera_rate_hz")
            if getattr(self, name) is None
        ]
        out += ImuNoise().missing() if self.imu is None else self.imu.missing()
        return out

    @property
    def is_complete(self) -> bool:
        """True when nothing is withheld."""
        return not self.missing()

    def require(self, *names: str) -> None:
        """Raise CalibrationError listing which of ``names`` are withheld.

        A name is a field of RIG_FIELDS or ``imu`` (all IMU fields); unknown names are a ValueError.
        """
        wanted: list[str] = []
        for name in names:
            if name == "imu":
                wanted += [f"imu.{f}" for f in IMU_FIELDS]
            elif name in RIG_FIELDS:
                wanted.append(name)
            else:
                raise ValueError(f"unknown rig field {name!r} (known: imu, {', '.join(RIG_FIELDS)})")
        missing = set(self.missing())
        withheld = [n for n in wanted if n in missing]
        if withheld:
            label = f"rig {self.name!r}" if self.name else "the rig"
            raise CalibrationError(
                f"{label} withholds {', '.join(withheld)}, which this step needs", None, withheld[0]
            )

    def __repr__(self) -> str:
        extrinsics = "None" if self.T_IC is None else f"<p_IC={np.round(self.T_IC[:3, 3], 6).tolist()} m>"
        return (
            f"Rig(name={self.name!r}, camera={self.camera!r}, T_IC={extrinsics}, "
            f"time_offset_s={self.time_offset_s}, imu={self.imu!r}, camera_rate_hz={self.camera_rate_hz})"
        )

    def replace(self, **changes: object) -> Rig:
        """A copy with some fields changed (validated again)."""
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        values.update(changes)
        return Rig(**values)  # type: ignore[arg-type]

    def isclose(self, other: object, rtol: float = 1e-9, atol: float = 1e-12) -> bool:
        """True when every field of ``other`` matches (numbers within tolerance; None only with None)."""
        if not isinstance(other, Rig):
            return False

        def same(a: object, b: object) -> bool:
            if a is None or b is None:
                return a is None and b is None
            if isinstance(a, CameraModel):
                return a.isclose(b, rtol, atol)
            return bool(np.allclose(np.asarray(a, dtype=float), np.asarray(b, dtype=float), rtol, atol))

        if not all(
            same(getattr(self, n), getattr(other, n))
            for n in ("camera", "T_IC", "time_offset_s", "camera_rate_hz")
        ):
            return False
        mine = self.imu if self.imu is not None else ImuNoise()  # None = every IMU field withheld
        theirs = other.imu if other.imu is not None else ImuNoise()
        return all(same(getattr(mine, n), getattr(theirs, n)) for n in IMU_FIELDS)
