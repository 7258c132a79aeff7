"""An OAK's factory calibration as a `calib.Rig`, and which direction of its camera-IMU extrinsics agrees
with gravity (the conventions are in `drivers.oak`'s docstring, "Calibration")."""
from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from runtime.errors import CalibrationError

if TYPE_CHECKING:
    from calib import Rig

EXTRINSICS_TOLERANCE = 1e-3
"""Largest |R^T R - I| of the factory IMU-to-camera rotation taken as a rotation (depthai stores float32,
about 1e-7); beyond it the stored matrix is corrupt (zeroed, a reflection, garbage) and is not used."""
RATIONAL_TOLERANCE = 1e-6
"""Perspective coefficients k4.. with |value| at most this count as zero (radtan is then exact; likewise
the thin-prism and tilt terms s1..ty, which no DAVIO camera model has)."""


def _orthonormal(T: np.ndarray) -> np.ndarray:
    """The nearest rigid transform (SVD of the rotation; depthai stores float32)."""
    U, _, Vt = np.linalg.svd(T[:3, :3])
    R = U @ Vt
    if np.linalg.det(R) < 0:
        U[:, -1] *= -1
        R = U @ Vt
    out = np.eye(4)
    out[:3, :3] = R
    out[:3, 3] = T[:3, 3]
    return out


def crop_intrinsics(K: np.ndarray, size: tuple[int, int], out: tuple[int, int]) -> np.ndarray:
    """K (3,3) of the image the Camera node's ImgResizeMode.CROP makes of a `size` = (W, H) image at `out`
    = (w, h): the largest centred region of the output's aspect ratio, in whole pixels, scaled to the
    output (depthai's `ImgTransformation` addCrop + addScale maths: coordinates scale, no half-pixel
    shift).

    depthai's `getCameraIntrinsics(socket, w, h)` is not that for every size: for a 4:3 output of a
    16:10 calibration it scales to fit the width and pads the height (640 x 480 of 1280 x 800 gives
    fx / 2 where the cropped image has 0.6 fx)."""
    (W, H), (w, h) = size, out
    s = max(w / W, h / H)
    cw, ch = min(W, round(w / s)), min(H, round(h / s))
    x0, y0 = (W - cw) // 2, (H - ch) // 2
    sx, sy = w / cw, h / ch
    K = np.asarray(K, np.float64)
    return np.array([[K[0, 0] * sx, 0.0, (K[0, 2] - x0) * sx], [0.0, K[1, 1] * sy, (K[1, 2] - y0) * sy],
                     [0.0, 0.0, 1.0]])


def read_oak_rig(calib: Any, socket: str = "CAM_B", width: int = 640, height: int = 400, *,
                 fps: float | None = None, time_offset_s: float | None = 0.0,
                 require_extrinsics: bool = False, notes: list[str] | None = None) -> Rig:
    """A `calib.Rig` from a `dai.CalibrationHandler` for one socket at one output size.

    Camera: the calibration's K at its own size (`getDefaultIntrinsics`) brought to the output size as
    the Camera node's CROP makes it (`crop_intrinsics`), and the distortion mapped as in the module
    docstring (CalibrationError naming the socket when the model is not representable). T_IC: the inverse
    of `getImuToCameraExtrinsics(socket, False, METER)` (x_C = M x_I; see the module docstring), in
    metres; None when the calibration holds no IMU extrinsics, or a matrix that is not a rigid transform
    (a corrupt EEPROM: zeroed, a reflection; said in `notes`), so that the hand-eye bring-up estimates
    them (CalibrationError with `require_extrinsics`). time_offset_s: 0 by default (camera and IMU share
    the device clock and the frames are stamped at mid-exposure). IMU noise: withheld (OAK calibrations
    do not carry it).
    """
    from calib import PinholeEquidistant, PinholeRadtan, PinholeRational, Rig
    from drivers.oak_pipeline import SOCKETS, _import_depthai, _one_line

    dai = _import_depthai()
    from calib.rig import invert_rigid

    if socket not in SOCKETS:
        raise CalibrationError(f"socket must be one of {', '.join(SOCKETS)}, not {socket!r}", None, "socket")
    sock = getattr(dai.CameraBoardSocket, socket)
    where = f"OAK calibration {socket}"
    try:
        K_cal, W, H = calib.getDefaultIntrinsics(sock)
        K = crop_intrinsics(np.array(K_cal, dtype=np.float64), (int(W), int(H)), (int(width), int(height)))
        model = calib.getDistortionModel(sock)
        coeffs = np.array(calib.getDistortionCoefficients(sock), dtype=np.float64)
    except RuntimeError as exc:
        raise CalibrationError(f"{where}: {_one_line(exc)}", None, "intrinsics") from None
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if model == dai.CameraModel.Perspective:
        c = np.zeros(14)
        c[: min(14, coeffs.size)] = coeffs[:14]
        prism = c[8:]
        if np.any(np.abs(prism) > RATIONAL_TOLERANCE):
            names = ("s1", "s2", "s3", "s4", "tx", "ty")
            named = ", ".join(f"{n}={v:.4g}" for n, v in zip(names, prism, strict=True)
                              if abs(v) > RATIONAL_TOLERANCE)
            raise CalibrationError(
                f"{where}: the lens uses OpenCV's thin-prism / tilted model ({named}), which DAVIO's camera "
                f"models (radtan, rational, equidistant) cannot represent; calibrate the camera with Kalibr "
                f"(pinhole-radtan or pinhole-equi) and pass that calibration instead", None, "distortion")
        if np.any(np.abs(c[5:8]) > RATIONAL_TOLERANCE):
            camera = PinholeRational(int(width), int(height), fx, fy, cx, cy, c[:8])
        else:
            dist = c[:5] if abs(c[4]) > RATIONAL_TOLERANCE else c[:4]
            camera = PinholeRadtan(int(width), int(height), fx, fy, cx, cy, dist)
    elif model == dai.CameraModel.Fisheye:
        if coeffs.size < 4:
            raise CalibrationError(f"{where}: a fisheye calibration with {coeffs.size} coefficients", None,
                                   "distortion")
        camera = PinholeEquidistant(int(width), int(height), fx, fy, cx, cy, coeffs[:4])
    else:
        raise CalibrationError(f"{where}: distortion model {model.name} is not supported (Perspective "
                               f"without thin-prism terms, or Fisheye)", None, "distortion")
    T_IC = None
    try:
        M = np.array(calib.getImuToCameraExtrinsics(sock, False, dai.LengthUnit.METER), dtype=np.float64)
    except RuntimeError as exc:
        if require_extrinsics:
            raise CalibrationError(f"{where}: {_one_line(exc)}", None, "T_IC") from None
    else:
        from calib.rig import rigid_problem

        problem = rigid_problem(M, EXTRINSICS_TOLERANCE)
        if problem is None:
            T_IC = invert_rigid(_orthonormal(M))
        else:
            text = f"{where}: the factory IMU-camera extrinsics are not a rigid transform ({problem})"
            if require_extrinsics:
                raise CalibrationError(f"{text}; pass a calibration with --rig", None, "T_IC")
            if notes is not None:
                notes.append(f"{text}: they are withheld, and the hand-eye bring-up estimates them (or pass "
                             f"a calibration with --rig; `davio calibrate oak` writes one)")
    return Rig(camera=camera, T_IC=T_IC, time_offset_s=time_offset_s, imu=None, camera_rate_hz=fps,
               name=f"oak {socket} {int(width)}x{int(height)}")


def check_extrinsics_direction(T_IC: np.ndarray, accel_at_rest_I: Sequence[float],
                               up_C: Sequence[float] = (0.0, -1.0, 0.0),
                               tol_deg: float = 10.0) -> dict[str, Any]:
    """Which direction of T_IC agrees with gravity at rest.

    At rest the accelerometer reads +g along "up": accel_I is parallel to R_IC @ up_C. `up_C` is "up"
    in camera coordinates while the samples were taken (held level, image upright: (0, -1, 0)).
    Returns the angles (degrees) between the measured accel and R_IC @ up_C ("as_given") and
    R_IC^T @ up_C ("inverse"), and a verdict: "as_given", "inverse", "ambiguous" (both agree: the
    rotation maps up_C to the same direction both ways, e.g. a 180 degree turn; only the translation
    differs and cannot be told from gravity) or "neither" (the camera was not level or the axes are
    wrong).
    """
    R = np.asarray(T_IC, dtype=np.float64)[:3, :3]
    a = np.asarray(accel_at_rest_I, dtype=np.float64).reshape(3)
    u = np.asarray(up_C, dtype=np.float64).reshape(3)
    if not (np.linalg.norm(a) > 0 and np.linalg.norm(u) > 0):
        raise ValueError("accel_at_rest_I and up_C must be non-zero vectors")
    a, u = a / np.linalg.norm(a), u / np.linalg.norm(u)

    def angle(v: np.ndarray) -> float:
        return math.degrees(math.acos(float(np.clip(a @ (v / np.linalg.norm(v)), -1.0, 1.0))))

    given, inverse = angle(R @ u), angle(R.T @ u)
    ok_g, ok_i = given <= tol_deg, inverse <= tol_deg
    verdict = ("ambiguous" if ok_g and ok_i else "as_given" if ok_g else "inverse" if ok_i else "neither")
    return {"angle_as_given_deg": given, "angle_inverse_deg": inverse, "verdict": verdict, "tol_deg": tol_deg}
