"""Camera projection kernels for the filter (numba): distortion, its Jacobian, undistortion.

The filter reads intrinsics from a calib camera object once (`CameraParams.from_camera`) and then
works on plain arrays. Models: "radtan" (k1 k2 p1 p2 [k3]), "rational" (k1 k2 p1 p2 k3 k4 k5 k6, OpenCV's:
radtan's radial term divided by 1 + k4 r^2 + k5 r^4 + k6 r^6; one kernel serves both, radtan with
k4..k6 = 0), "equidistant" (k1..k4), "none".
Pixels follow OpenCV: (0, 0) is the centre of the top-left pixel.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from runtime.errors import CalibrationError

MODEL_CODES = {"none": 0, "radtan": 1, "equidistant": 2, "rational": 1}


@dataclass(frozen=True)
class CameraParams:
    """Pinhole intrinsics plus a distortion model; `params` = [fx, fy, cx, cy, d0, ..., d7] (unused: 0)."""

    model: str
    params: np.ndarray
    width: int
    height: int

    @property
    def code(self) -> int:
        return MODEL_CODES[self.model]

    @staticmethod
    def from_camera(camera: object) -> CameraParams:
        """From a calib camera (fx, fy, cx, cy, distortion, width, height; class name gives the model)."""
        name = type(camera).__name__.lower()
        model = getattr(camera, "distortion_model", None)
        if model is None:
            model = "equidistant" if "equidistant" in name else "radtan" if "radtan" in name else "none"
        model = {"plumb_bob": "radtan", "radial-tangential": "radtan", "equi": "equidistant",
                 "fisheye": "equidistant", "pinhole": "none"}.get(str(model).lower(), str(model).lower())
        if model not in MODEL_CODES:
            raise CalibrationError(f"unsupported distortion model {model!r} for the MSCKF")
        d = np.zeros(8)
        dist = np.asarray(getattr(camera, "distortion", np.zeros(0)), dtype=float).ravel()
        most = {"radtan": 5, "rational": 8}.get(model, 4)
        if dist.size > most or (model == "rational" and dist.size != 8):
            raise CalibrationError(f"{model} distortion with {dist.size} coefficients is not supported")
        d[: dist.size] = dist
        if model != "none" and dist.size == 0:
            model = "none"
        p = np.array([camera.fx, camera.fy, camera.cx, camera.cy, *d], dtype=float)
        if not (np.all(np.isfinite(p)) and p[0] > 0 and p[1] > 0):
            raise CalibrationError(f"invalid intrinsics {p[:4]}")
        return CameraParams(model, p, int(getattr(camera, "width", 0)), int(getattr(camera, "height", 0)))


@njit(cache=True, nogil=True)
def distort_point(code: int, prm: np.ndarray, x: float, y: float) -> tuple:
    """Normalised (x, y) -> pixel (u, v) and the 2x2 Jacobian d(u,v)/d(x,y)."""
    fx, fy, cx, cy = prm[0], prm[1], prm[2], prm[3]
    J = np.zeros((2, 2))
    if code == 1:
        k1, k2, p1, p2, k3 = prm[4], prm[5], prm[6], prm[7], prm[8]
        k4, k5, k6 = (prm[9], prm[10], prm[11]) if prm.shape[0] >= 12 else (0.0, 0.0, 0.0)
        r2 = x * x + y * y
        num = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
        den = 1.0 + k4 * r2 + k5 * r2 * r2 + k6 * r2 * r2 * r2       # 1 for radtan: exact, as before
        rad = num / den
        xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        dnum = k1 + 2 * k2 * r2 + 3 * k3 * r2 * r2
        dden = k4 + 2 * k5 * r2 + 3 * k6 * r2 * r2
        drad = (dnum * den - num * dden) / (den * den)  # d rad / d r2
        dxd_dx = rad + x * drad * 2 * x + 2 * p1 * y + p2 * 6 * x
        dxd_dy = x * drad * 2 * y + 2 * p1 * x + p2 * 2 * y
        dyd_dx = y * drad * 2 * x + p1 * 2 * x + 2 * p2 * y
        dyd_dy = rad + y * drad * 2 * y + p1 * 6 * y + 2 * p2 * x
        J[0, 0] = fx * dxd_dx
        J[0, 1] = fx * dxd_dy
        J[1, 0] = fy * dyd_dx
        J[1, 1] = fy * dyd_dy
        return fx * xd + cx, fy * yd + cy, J
    if code == 2:
        k1, k2, k3, k4 = prm[4], prm[5], prm[6], prm[7]
        r = np.sqrt(x * x + y * y)
        if r < 1e-10:
            J[0, 0] = fx
            J[1, 1] = fy
            return fx * x + cx, fy * y + cy, J
        th = np.arctan(r)
        t2 = th * th
        thd = th * (1 + k1 * t2 + k2 * t2 * t2 + k3 * t2 * t2 * t2 + k4 * t2 * t2 * t2 * t2)
        s = thd / r
        dthd_dth = 1 + 3 * k1 * t2 + 5 * k2 * t2 * t2 + 7 * k3 * t2 * t2 * t2 + 9 * k4 * t2 * t2 * t2 * t2
        dth_dr = 1.0 / (1.0 + r * r)
        ds_dr = (dthd_dth * dth_dr * r - thd) / (r * r)
        dr_dx = x / r
        dr_dy = y / r
        J[0, 0] = fx * (s + x * ds_dr * dr_dx)
        J[0, 1] = fx * (x * ds_dr * dr_dy)
        J[1, 0] = fy * (y * ds_dr * dr_dx)
        J[1, 1] = fy * (s + y * ds_dr * dr_dy)
        return fx * x * s + cx, fy * y * s + cy, J
    J[0, 0] = fx
    J[1, 1] = fy
    return fx * x + cx, fy * y + cy, J


@njit(cache=True, nogil=True)
def undistort_points(code: int, prm: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) -> normalised coordinates (N, 2) by Gauss-Newton on the distortion model."""
    n = uv.shape[0]
    out = np.empty((n, 2))
    for i in range(n):
        x = (uv[i, 0] - prm[2]) / prm[0]
        y = (uv[i, 1] - prm[3]) / prm[1]
        if code != 0:
            for _ in range(20):
                u, v, J = distort_point(code, prm, x, y)
                eu = uv[i, 0] - u
                ev = uv[i, 1] - v
                det = J[0, 0] * J[1, 1] - J[0, 1] * J[1, 0]
                if det == 0.0:
                    break
                dx = (J[1, 1] * eu - J[0, 1] * ev) / det
                dy = (-J[1, 0] * eu + J[0, 0] * ev) / det
                x += dx
                y += dy
                if dx * dx + dy * dy < 1e-24:
                    break
        out[i, 0] = x
        out[i, 1] = y
    return out


@njit(cache=True, nogil=True)
def distort_points(code: int, prm: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Normalised coordinates (N, 2) -> pixels (N, 2)."""
    n = xy.shape[0]
    out = np.empty((n, 2))
    for i in range(n):
        u, v, _ = distort_point(code, prm, xy[i, 0], xy[i, 1])
        out[i, 0] = u
        out[i, 1] = v
    return out


#: number of estimated intrinsics: fx, fy, cx, cy and four distortion coefficients
#: (radtan and rational k1 k2 p1 p2, equidistant k1..k4; k3..k6 stay fixed), as OpenVINS's
#: calib_cam_intrinsics
NUM_INTRINSICS = 8


@njit(cache=True, nogil=True)
def distort_jacobian_params(code: int, prm: np.ndarray, x: float, y: float) -> np.ndarray:
    """d(u, v) / d(prm[:8]) at normalised (x, y): the (2, 8) Jacobian of the distorted pixel w.r.t.
    [fx, fy, cx, cy, d0, d1, d2, d3] (pixels per unit of each parameter). Model "none": zero distortion
    columns."""
    fx, fy = prm[0], prm[1]
    J = np.zeros((2, 8))
    J[0, 2] = 1.0
    J[1, 3] = 1.0
    if code == 1:
        k1, k2, p1, p2, k3 = prm[4], prm[5], prm[6], prm[7], prm[8]
        r2 = x * x + y * y
        den = 1.0
        if prm.shape[0] >= 12:                     # rational (radtan: k4..k6 = 0, or a 9-value array)
            den = 1.0 + prm[9] * r2 + prm[10] * r2 * r2 + prm[11] * r2 * r2 * r2
        rad = (1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2) / den
        xy2 = 2.0 * x * y
        J[0, 0] = x * rad + p1 * xy2 + p2 * (r2 + 2.0 * x * x)
        J[1, 1] = y * rad + p1 * (r2 + 2.0 * y * y) + p2 * xy2
        J[0, 4] = fx * x * r2 / den
        J[1, 4] = fy * y * r2 / den
        J[0, 5] = fx * x * r2 * r2 / den
        J[1, 5] = fy * y * r2 * r2 / den
        J[0, 6] = fx * xy2
        J[1, 6] = fy * (r2 + 2.0 * y * y)
        J[0, 7] = fx * (r2 + 2.0 * x * x)
        J[1, 7] = fy * xy2
        return J
    if code == 2:
        r = np.sqrt(x * x + y * y)
        if r < 1e-10:
            J[0, 0] = x
            J[1, 1] = y
            return J
        th = np.arctan(r)
        t2 = th * th
        thd = th * (1 + prm[4] * t2 + prm[5] * t2 * t2 + prm[6] * t2 * t2 * t2 + prm[7] * t2 * t2 * t2 * t2)
        s = thd / r
        J[0, 0] = x * s
        J[1, 1] = y * s
        tp = th  # theta^(2j+1) for j = 1..4
        for j in range(4):
            tp = tp * t2
            J[0, 4 + j] = fx * x / r * tp
            J[1, 4 + j] = fy * y / r * tp
        return J
    J[0, 0] = x
    J[1, 1] = y
    return J
