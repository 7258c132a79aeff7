"""Camera models: pinhole, pinhole + radial-tangential, pinhole + equidistant (fisheye).

Conventions: points in the camera frame C (x right, y down, z forward, metres); normalized
coordinates xy = (X/Z, Y/Z); pixels (u, v) with (0, 0) at the centre of the top-left pixel
(OpenCV). The distortion formulas are those of OpenCV / Kalibr:

- radtan: ``(k1, k2, p1, p2[, k3])``, OpenCV ``cv2.projectPoints`` / Kalibr ``radtan``;
- equidistant: ``(k1, k2, k3, k4)``, OpenCV ``cv2.fisheye`` / Kalibr ``equidistant``.

Constructors validate their numbers and raise :class:`CalibrationError` whose ``key`` is one of
``resolution``, ``intrinsics`` or ``distortion`` (readers re-key it to the file's own key).
Array methods accept any leading shape ``(..., 2)`` / ``(..., 3)`` and keep it.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod

import numpy as np

from runtime.errors import CalibrationError

#: Newton iterations and tolerance (normalized units) of the point undistortion.
UNDISTORT_MAX_ITERATIONS = 30
UNDISTORT_TOLERANCE = 1e-13
#: A point whose undistortion residual stays above this (normalized units) is reported as NaN.
UNDISTORT_ACCEPT = 1e-9


def _last_axis(a: np.ndarray | list, n: int, name: str) -> np.ndarray:
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim == 0 or arr.shape[-1] != n:
        raise ValueError(f"{name} must have shape (..., {n}), got {arr.shape}")
    return arr


def _positive_int(value: object, key: str, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or int(value) <= 0:
        raise CalibrationError(f"{what} must be a positive integer, got {value!r}", None, key)
    return int(value)


MAX_DISTORTION = 1e4
"""Largest distortion coefficient accepted (OpenCV's rational model fits reach tens; values near 1e300
overflow the projection to inf inside the filter's kernels)."""


def _finite(value: object, key: str, what: str, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise CalibrationError(f"{what} must be a number, got {value!r}", None, key)
    f = float(value)
    if not math.isfinite(f):
        raise CalibrationError(f"{what} must be finite, got {f}", None, key)
    if positive and f <= 0.0:
        raise CalibrationError(f"{what} must be positive, got {f}", None, key)
    return f


class CameraModel(ABC):
    """A calibrated monocular camera: image size, pinhole intrinsics and a lens distortion.

    Attributes:
        width, height: image size in pixels.
        fx, fy: focal lengths in pixels; cx, cy: principal point in pixels.
        distortion: read-only float64 vector of distortion coefficients (model specific).
    """

    #: Name of the distortion model as written to Kalibr files (``none``, ``radtan``, ``equidistant``, and
    #: DAVIO's ``rational``).
    distortion_model: str = ""
    #: Allowed lengths of the distortion vector.
    distortion_sizes: tuple[int, ...] = ()

    def __init__(
        self,
        width: int,
        height: int,
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        distortion: np.ndarray | list | tuple = (),
    ) -> None:
        self.width = _positive_int(width, "resolution", "image width")
        self.height = _positive_int(height, "resolution", "image height")
        self.fx = _finite(fx, "intrinsics", "fx", positive=True)
        self.fy = _finite(fy, "intrinsics", "fy", positive=True)
        self.cx = _finite(cx, "intrinsics", "cx")
        self.cy = _finite(cy, "intrinsics", "cy")
        coeffs = list(distortion)
        if len(coeffs) not in self.distortion_sizes:
            raise CalibrationError(
                f"the {self.distortion_model} model needs {' or '.join(map(str, self.distortion_sizes))} "
                f"distortion coefficients, got {len(coeffs)}",
                None,
                "distortion",
            )
        d = np.array([_finite(c, "distortion", f"distortion coefficient {i}") for i, c in enumerate(coeffs)])
        if np.any(np.abs(d) > MAX_DISTORTION):
            i = int(np.argmax(np.abs(d)))
            raise CalibrationError(f"distortion coefficient {i} is {d[i]:g}: no lens model fit gives one "
                                   f"above {MAX_DISTORTION:g} in size (a mangled number?)", None,
                                   "distortion")
        d.setflags(write=False)
        self.distortion = d

    # ----------------------------------------------------------------- intrinsics
    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix (pixels)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels, the order OpenCV uses."""
        return (self.width, self.height)

    @property
    def is_pinhole_rectified(self) -> bool:
        """True when the model has no (or only zero) distortion: pixels are a pure pinhole projection."""
        return not np.any(self.distortion)

    def _with(self, width: int, height: int, fx: float, fy: float, cx: float, cy: float) -> CameraModel:
        return type(self)(width, height, fx, fy, cx, cy, self.distortion)

    def scaled(self, sx: float, sy: float) -> CameraModel:
        """The same camera after resizing the image by (sx, sy).

        Focal lengths scale; the principal point follows the pixel-centre convention
        ``c' = (c + 0.5) s - 0.5``; the size becomes ``round(width sx) x round(height sy)``.
        Distortion acts on normalized coordinates and is unchanged.
        """
        sx = _finite(sx, "scale", "sx", positive=True)
        sy = _finite(sy, "scale", "sy", positive=True)
        return self._with(
            max(1, round(self.width * sx)),
            max(1, round(self.height * sy)),
            self.fx * sx,
            self.fy * sy,
            (self.cx + 0.5) * sx - 0.5,
            (self.cy + 0.5) * sy - 0.5,
        )

    def resized(self, width: int, height: int) -> CameraModel:
        """The same camera for an image resized to exactly (width, height) pixels."""
        width = _positive_int(width, "resolution", "width")
        height = _positive_int(height, "resolution", "height")
        sx, sy = width / self.width, height / self.height
        return self._with(
            width, height, self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5
        )

    def pinhole(self, K_new: np.ndarray | None = None, size: tuple[int, int] | None = None) -> Pinhole:
        """The distortion-free camera that the undistortion maps produce (K_new, default K)."""
        K = self.K if K_new is None else np.asarray(K_new, dtype=np.float64)
        if K.shape != (3, 3):
            raise ValueError(f"K_new must be 3x3, got {K.shape}")
        w, h = self.size if size is None else size
        return Pinhole(w, h, K[0, 0], K[1, 1], K[0, 2], K[1, 2])

    # ----------------------------------------------------------------- distortion (model specific)
    @abstractmethod
    def _distort_normalized(self, xy: np.ndarray) -> np.ndarray:
        """Distorted normalized coordinates (N,2) of undistorted normalized ones (N,2)."""

    @abstractmethod
    def _distort_normalized_jacobian(self, xy: np.ndarray) -> np.ndarray:
        """(N,2,2) derivative of the distorted normalized coordinates w.r.t. the undistorted ones."""

    def _undistort_normalized(self, xy_d: np.ndarray) -> np.ndarray:
        """Invert the distortion by Newton's method on all points at once (N,2) -> (N,2).

        Rows that do not converge to within UNDISTORT_ACCEPT are NaN.
        """
        xy = xy_d.copy()
        for _ in range(UNDISTORT_MAX_ITERATIONS):
            residual = self._distort_normalized(xy) - xy_d
            if not np.any(np.abs(residual) > UNDISTORT_TOLERANCE):
                break
            J = self._distort_normalized_jacobian(xy)
            det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
            det = np.where(np.abs(det) < 1e-12, np.nan, det)
            step_x = (J[:, 1, 1] * residual[:, 0] - J[:, 0, 1] * residual[:, 1]) / det
            step_y = (-J[:, 1, 0] * residual[:, 0] + J[:, 0, 0] * residual[:, 1]) / det
            xy = xy - np.stack([step_x, step_y], axis=-1)
        residual = self._distort_normalized(xy) - xy_d
        bad = ~(np.max(np.abs(residual), axis=-1) <= UNDISTORT_ACCEPT)
        xy[bad] = np.nan
        return xy

    # ----------------------------------------------------------------- public projection API
    def distort(self, xy: np.ndarray) -> np.ndarray:
        """Pixels (..., 2) of undistorted normalized coordinates xy = (X/Z, Y/Z) (..., 2)."""
        xy = _last_axis(xy, 2, "xy")
        d = self._distort_normalized(xy.reshape(-1, 2))
        uv = np.empty_like(d)
        uv[:, 0] = self.fx * d[:, 0] + self.cx
        uv[:, 1] = self.fy * d[:, 1] + self.cy
        return uv.reshape(xy.shape)

    def distort_jacobian(self, xy: np.ndarray) -> np.ndarray:
        """(..., 2, 2) derivative of the pixel (u, v) w.r.t. the normalized coordinates (x, y)."""
        xy = _last_axis(xy, 2, "xy")
        J = self._distort_normalized_jacobian(xy.reshape(-1, 2))
        J[:, 0, :] *= self.fx
        J[:, 1, :] *= self.fy
        return J.reshape(xy.shape[:-1] + (2, 2))

    def project(self, p_C: np.ndarray) -> np.ndarray:
        """Pixels (..., 2) of 3-D points p_C (..., 3) in the camera frame; NaN rows where Z <= 0."""
        p = _last_axis(p_C, 3, "p_C").reshape(-1, 3)
        z = np.where(p[:, 2] > 0.0, p[:, 2], np.nan)
        uv = self.distort(p[:, :2] / z[:, None])
        return uv.reshape(np.shape(p_C)[:-1] + (2,))

    def project_jacobian(self, p_C: np.ndarray) -> np.ndarray:
        """(..., 2, 3) analytic derivative of project() w.r.t. p_C (pixels per metre); NaN where Z <= 0."""
        p = _last_axis(p_C, 3, "p_C").reshape(-1, 3)
        inv_z = 1.0 / np.where(p[:, 2] > 0.0, p[:, 2], np.nan)
        xy = p[:, :2] * inv_z[:, None]
        J_uv_xy = self.distort_jacobian(xy)
        J_xy_p = np.zeros((p.shape[0], 2, 3))
        J_xy_p[:, 0, 0] = inv_z
        J_xy_p[:, 1, 1] = inv_z
        J_xy_p[:, 0, 2] = -xy[:, 0] * inv_z
        J_xy_p[:, 1, 2] = -xy[:, 1] * inv_z
        return (J_uv_xy @ J_xy_p).reshape(np.shape(p_C)[:-1] + (2, 3))

    def undistort_points(self, uv: np.ndarray) -> np.ndarray:
        """Undistorted normalized coordinates (..., 2) of pixels (..., 2) (iterative inverse of distort).

        Agrees with ``cv2.undistortPoints`` / ``cv2.fisheye.undistortPoints`` run to convergence;
        rows where the inversion does not converge are NaN.
        """
        uv = _last_axis(uv, 2, "uv")
        flat = uv.reshape(-1, 2)
        xy_d = np.empty_like(flat)
        xy_d[:, 0] = (flat[:, 0] - self.cx) / self.fx
        xy_d[:, 1] = (flat[:, 1] - self.cy) / self.fy
        return self._undistort_normalized(xy_d).reshape(uv.shape)

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        """Rays (..., 3) with Z = 1 in the camera frame through pixels (..., 2)."""
        xy = self.undistort_points(uv)
        return np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1)

    def undistortion_maps(
        self, K_new: np.ndarray | None = None, size: tuple[int, int] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Float32 (map_x, map_y), each (height, width), for ``cv2.remap`` to a distortion-free image.

        The output image is the pinhole camera ``K_new`` (default K) of ``size`` = (width, height)
        (default this camera's size); each output pixel samples the source at the distorted
        projection of its ray. Equivalent to ``cv2.initUndistortRectifyMap`` (or its fisheye
        version) with R = I and m1type CV_32FC1.
        """
        target = self.pinhole(K_new, size)
        u, v = np.meshgrid(
            np.arange(target.width, dtype=np.float64), np.arange(target.height, dtype=np.float64)
        )
        xy = np.stack([(u - target.cx) / target.fx, (v - target.cy) / target.fy], axis=-1)
        uv = self.distort(xy)
        return uv[..., 0].astype(np.float32), uv[..., 1].astype(np.float32)

    # ----------------------------------------------------------------- comparison / display
    def isclose(self, other: object, rtol: float = 1e-9, atol: float = 1e-12) -> bool:
        """True when ``other`` is the same model with the same size and (numerically) equal numbers."""
        if type(other) is not type(self):
            return False
        assert isinstance(other, CameraModel)
        return (
            self.size == other.size
            and np.allclose(
                [self.fx, self.fy, self.cx, self.cy], [other.fx, other.fy, other.cx, other.cy], rtol, atol
            )
            and self.distortion.shape == other.distortion.shape
            and np.allclose(self.distortion, other.distortion, rtol, atol)
        )

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}({self.width}x{self.height}, fx={self.fx:g}, fy={self.fy:g}, "
            f"cx={self.cx:g}, cy={self.cy:g}, distortion={self.distortion.tolist()})"
        )


class Pinhole(CameraModel):
    """Distortion-free pinhole camera (rectified images)."""

    distortion_model = "none"
    distortion_sizes = (0,)

    def _distort_normalized(self, xy: np.ndarray) -> np.ndarray:
        return xy.copy()

    def _distort_normalized_jacobian(self, xy: np.ndarray) -> np.ndarray:
        J = np.zeros((xy.shape[0], 2, 2))
        J[:, 0, 0] = 1.0
        J[:, 1, 1] = 1.0
        return J

    def _undistort_normalized(self, xy_d: np.ndarray) -> np.ndarray:
        return xy_d.copy()


class PinholeRadtan(CameraModel):
    """Pinhole + radial-tangential (plumb bob) distortion ``(k1, k2, p1, p2[, k3])``.

    With r^2 = x^2 + y^2 and radial = 1 + k1 r^2 + k2 r^4 + k3 r^6:
    x_d = x radial + 2 p1 x y + p2 (r^2 + 2 x^2),  y_d = y radial + p1 (r^2 + 2 y^2) + 2 p2 x y.
    """

    distortion_model = "radtan"
    distortion_sizes = (4, 5)

    def _coefficients(self) -> tuple[float, float, float, float, float]:
        d = self.distortion
        k3 = float(d[4]) if d.size == 5 else 0.0
        return float(d[0]), float(d[1]), float(d[2]), float(d[3]), k3

    def _distort_normalized(self, xy: np.ndarray) -> np.ndarray:
        k1, k2, p1, p2, k3 = self._coefficients()
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return np.stack([xd, yd], axis=-1)

    def _undistort_normalized(self, xy_d: np.ndarray) -> np.ndarray:
        """Newton's method per point in a numba kernel (the tracker's hot path)."""
        from calib.radtan_kernel import undistort_radtan  # numba only when undistorting: calib stays light

        k1, k2, p1, p2, k3 = self._coefficients()
        return undistort_radtan(np.ascontiguousarray(xy_d, dtype=np.float64), k1, k2, p1, p2, k3,
                                UNDISTORT_MAX_ITERATIONS, UNDISTORT_TOLERANCE, UNDISTORT_ACCEPT)

    def _distort_normalized_jacobian(self, xy: np.ndarray) -> np.ndarray:
        k1, k2, p1, p2, k3 = self._coefficients()
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        d_radial_d_r2 = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
        J = np.empty((xy.shape[0], 2, 2))
        J[:, 0, 0] = radial + 2.0 * x * x * d_radial_d_r2 + 2.0 * p1 * y + 6.0 * p2 * x
        J[:, 0, 1] = 2.0 * x * y * d_radial_d_r2 + 2.0 * p1 * x + 2.0 * p2 * y
        J[:, 1, 0] = 2.0 * x * y * d_radial_d_r2 + 2.0 * p1 * x + 2.0 * p2 * y
        J[:, 1, 1] = radial + 2.0 * y * y * d_radial_d_r2 + 6.0 * p1 * y + 2.0 * p2 * x
        return J


class PinholeEquidistant(CameraModel):
    """Pinhole + equidistant (Kannala-Brandt / OpenCV fisheye) distortion ``(k1, k2, k3, k4)``.

    With r = |xy|, theta = atan(r) and theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 +
    k4 theta^8): xy_d = (theta_d / r) xy.
    """

    distortion_model = "equidistant"
    distortion_sizes = (4,)

    #: Below this radius the scale theta_d / r and its derivative use their series limits.
    _SMALL_R = 1e-8

    def _theta_d(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """theta_d(theta) and d theta_d / d theta."""
        k1, k2, k3, k4 = (float(c) for c in self.distortion)
        t2 = theta * theta
        poly = 1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))
        dpoly = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))
        return theta * poly, dpoly

    def _scale(self, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """s(r) = theta_d / r and (ds/dr) / r, both finite at r = 0."""
        k1 = float(self.distortion[0])
        small = r < self._SMALL_R
        r_safe = np.where(small, 1.0, r)
        theta = np.arctan(r_safe)
        theta_d, dtheta_d = self._theta_d(theta)
        s = theta_d / r_safe
        ds_dr = (dtheta_d / (1.0 + r_safe * r_safe) - s) / r_safe
        s = np.where(small, 1.0, s)
        ds_dr_over_r = np.where(small, 2.0 * (k1 - 1.0 / 3.0), ds_dr / r_safe)
        return s, ds_dr_over_r

    def _distort_normalized(self, xy: np.ndarray) -> np.ndarray:
        r = np.hypot(xy[:, 0], xy[:, 1])
        s, _ = self._scale(r)
        return xy * s[:, None]

    def _distort_normalized_jacobian(self, xy: np.ndarray) -> np.ndarray:
        r = np.hypot(xy[:, 0], xy[:, 1])
        s, ds_dr_over_r = self._scale(r)
        J = ds_dr_over_r[:, None, None] * (xy[:, :, None] * xy[:, None, :])
        J[:, 0, 0] += s
        J[:, 1, 1] += s
        return J

    def _undistort_normalized(self, xy_d: np.ndarray) -> np.ndarray:
        """Invert theta_d(theta) by 1-D Newton, then xy = tan(theta) xy_d / theta_d."""
        theta_d = np.hypot(xy_d[:, 0], xy_d[:, 1])
        theta = theta_d.copy()
        for _ in range(UNDISTORT_MAX_ITERATIONS):
            f, df = self._theta_d(theta)
            residual = f - theta_d
            if not np.any(np.abs(residual) > UNDISTORT_TOLERANCE):
                break
            theta = theta - residual / np.where(np.abs(df) < 1e-12, np.nan, df)
        f, _ = self._theta_d(theta)
        bad = ~(np.abs(f - theta_d) <= UNDISTORT_ACCEPT) | ~(np.abs(theta) < 0.5 * math.pi) | (theta < 0.0)
        small = theta_d < self._SMALL_R
        ratio = np.where(small, 1.0, np.tan(theta) / np.where(small, 1.0, theta_d))
        xy = xy_d * ratio[:, None]
        xy[bad] = np.nan
        return xy


class PinholeRational(CameraModel):
    """Pinhole + OpenCV's rational distortion ``(k1, k2, p1, p2, k3, k4, k5, k6)`` (CALIB_RATIONAL_MODEL;
    ROS's ``rational_polynomial``), the model of many factory calibrations (Luxonis OAK):

    radial = (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6), the tangential terms as
    radtan. With k4 = k5 = k6 = 0 it is radtan with k3. Kalibr and OpenVINS have no such model.
    """

    distortion_model = "rational"
    distortion_sizes = (8,)

    def _terms(self, xy: np.ndarray) -> tuple:
        k1, k2, p1, p2, k3, k4, k5, k6 = (float(v) for v in self.distortion)
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
        d_num = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
        d_den = k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2)
        radial = num / den
        d_radial = (d_num * den - num * d_den) / (den * den)      # d radial / d r^2
        return x, y, r2, radial, d_radial, p1, p2

    def _distort_normalized(self, xy: np.ndarray) -> np.ndarray:
        x, y, r2, radial, _, p1, p2 = self._terms(xy)
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return np.stack([xd, yd], axis=-1)

    def _distort_normalized_jacobian(self, xy: np.ndarray) -> np.ndarray:
        x, y, _, radial, d_radial, p1, p2 = self._terms(xy)
        J = np.empty((xy.shape[0], 2, 2))
        J[:, 0, 0] = radial + 2.0 * x * x * d_radial + 2.0 * p1 * y + 6.0 * p2 * x
        J[:, 0, 1] = 2.0 * x * y * d_radial + 2.0 * p1 * x + 2.0 * p2 * y
        J[:, 1, 0] = J[:, 0, 1]
        J[:, 1, 1] = radial + 2.0 * y * y * d_radial + 6.0 * p1 * y + 2.0 * p2 * x
        return J


#: Distortion-model names accepted by the readers (Kalibr, EuRoC, OpenCV spellings) -> class.
DISTORTION_MODELS: dict[str, type[CameraModel]] = {
    "none": Pinhole,
    "radtan": PinholeRadtan,
    "radial-tangential": PinholeRadtan,
    "radial_tangential": PinholeRadtan,
    "plumb_bob": PinholeRadtan,
    "equidistant": PinholeEquidistant,
    "equi": PinholeEquidistant,
    "fisheye": PinholeEquidistant,
    "rational": PinholeRational,
    "rational_polynomial": PinholeRational,
}


def camera_class(distortion_model: str) -> type[CameraModel]:
    """The camera class for a distortion-model name (case-insensitive); CalibrationError if unknown."""
    cls = DISTORTION_MODELS.get(str(distortion_model).strip().lower())
    if cls is None:
        raise CalibrationError(
            f"unknown distortion model {distortion_model!r} (known: {', '.join(sorted(DISTORTION_MODELS))})",
            None,
            "distortion_model",
        )
    return cls
