"""Camera models vs OpenCV (projectPoints, undistortPoints, fisheye, remap maps) and finite differences."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from calib import CameraModel, Pinhole, PinholeEquidistant, PinholeRadtan, PinholeRational, camera_class
from runtime.errors import CalibrationError

# EuRoC cam0 (radtan), the same with a k3 term, and a TUM-VI-like fisheye (equidistant).
EUROC = PinholeRadtan(
    752, 480, 458.654, 457.296, 367.215, 248.375, [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
)
RADTAN5 = PinholeRadtan(640, 480, 520.0, 515.0, 321.0, 238.5, [-0.12, 0.03, 0.001, -0.0008, -0.004])
FISHEYE = PinholeEquidistant(
    512, 512, 190.978, 190.973, 254.932, 256.897, [0.0034823, 0.0007150, -0.0020532, 0.0002029]
)
PINHOLE = Pinhole(640, 480, 500.0, 505.0, 320.5, 240.5)
# OpenCV's rational model with the coefficients of an OAK-D factory calibration (EEPROM dump's order
# k1 k2 p1 p2 k3 k4 k5 k6), on a 1280 x 800 mono camera
RATIONAL = PinholeRational(1280, 800, 800.0, 800.5, 640.5, 400.25,
                           [9.49, -102.07, 0.0008, 0.0020, 401.19, 9.26, -100.43, 394.56])

CV_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)


def _points_in_fov(cam: CameraModel, n: int, seed: int, max_angle_deg: float) -> np.ndarray:
    """Random 3-D points in front of the camera whose projection falls inside the image."""
    rng = np.random.default_rng(seed)
    out = []
    while sum(len(o) for o in out) < n:
        angle = np.deg2rad(max_angle_deg) * np.sqrt(rng.uniform(0.0, 1.0, 4 * n))
        azimuth = rng.uniform(0.0, 2 * np.pi, 4 * n)
        depth = rng.uniform(0.3, 30.0, 4 * n)
        xy = np.tan(angle)[:, None] * np.stack([np.cos(azimuth), np.sin(azimuth)], axis=-1)
        p = np.concatenate([xy, np.ones((4 * n, 1))], axis=1) * depth[:, None]
        uv = cam.project(p)
        inside = (uv[:, 0] > 0) & (uv[:, 0] < cam.width - 1) & (uv[:, 1] > 0) & (uv[:, 1] < cam.height - 1)
        out.append(p[inside])
    return np.concatenate(out)[:n]


CASES = [(EUROC, 60.0), (RADTAN5, 45.0), (PINHOLE, 40.0), (RATIONAL, 45.0)]


@pytest.mark.parametrize("cam,max_angle", CASES)
def test_project_matches_cv2_project_points(cam: CameraModel, max_angle: float) -> None:
    p = _points_in_fov(cam, 500, 1, max_angle)
    dist = cam.distortion if cam.distortion.size else np.zeros(4)
    uv_cv, jac_cv = cv2.projectPoints(p.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), cam.K, dist)
    np.testing.assert_allclose(cam.project(p), uv_cv.reshape(-1, 2), atol=1e-8)
    # with rvec = 0 the derivative w.r.t. tvec is the derivative w.r.t. p_C
    J = cam.project_jacobian(p)
    J_cv = jac_cv[:, 3:6].reshape(-1, 2, 3)
    np.testing.assert_allclose(J, J_cv, rtol=1e-7, atol=1e-6)


def test_fisheye_project_matches_cv2_fisheye() -> None:
    p = _points_in_fov(FISHEYE, 500, 2, 85.0)
    uv_cv, _ = cv2.fisheye.projectPoints(
        p.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), FISHEYE.K, FISHEYE.distortion
    )
    np.testing.assert_allclose(FISHEYE.project(p), uv_cv.reshape(-1, 2), atol=1e-8)


ALL = [(EUROC, 60.0), (RADTAN5, 45.0), (PINHOLE, 40.0), (FISHEYE, 85.0)]


@pytest.mark.parametrize("cam,max_angle", ALL)
def test_project_jacobian_matches_finite_differences(cam: CameraModel, max_angle: float) -> None:
    p = _points_in_fov(cam, 200, 3, max_angle)
    J = cam.project_jacobian(p)
    h = 1e-6
    for k in range(3):
        dp = np.zeros(3)
        dp[k] = h * np.abs(p[:, 2]).mean()
        fd = (cam.project(p + dp) - cam.project(p - dp)) / (2 * dp[k])
        np.testing.assert_allclose(J[:, :, k], fd, rtol=1e-5, atol=1e-4)


@pytest.mark.parametrize("cam,max_angle", ALL)
def test_distort_jacobian_matches_finite_differences(cam: CameraModel, max_angle: float) -> None:
    p = _points_in_fov(cam, 200, 4, max_angle)
    xy = p[:, :2] / p[:, 2:]
    J = cam.distort_jacobian(xy)
    h = 1e-7
    for k in range(2):
        d = np.zeros(2)
        d[k] = h
        fd = (cam.distort(xy + d) - cam.distort(xy - d)) / (2 * h)
        np.testing.assert_allclose(J[:, :, k], fd, rtol=1e-5, atol=1e-3)


def test_fisheye_jacobian_near_the_optical_axis() -> None:
    """The series limit at r -> 0 joins the general formula smoothly."""
    xy = np.array([[0.0, 0.0], [1e-9, -2e-9], [3e-6, 1e-6]])
    J = FISHEYE.distort_jacobian(xy)
    np.testing.assert_allclose(J[0], np.diag([FISHEYE.fx, FISHEYE.fy]), rtol=1e-12)
    np.testing.assert_allclose(J[1], np.diag([FISHEYE.fx, FISHEYE.fy]), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(J[2], np.diag([FISHEYE.fx, FISHEYE.fy]), rtol=1e-8, atol=1e-6)


@pytest.mark.parametrize("cam,max_angle", CASES)
def test_undistort_points_matches_cv2(cam: CameraModel, max_angle: float) -> None:
    p = _points_in_fov(cam, 500, 5, max_angle)
    uv = cam.project(p)
    dist = cam.distortion if cam.distortion.size else np.zeros(4)
    xy_cv = cv2.undistortPoints(uv.reshape(-1, 1, 2), cam.K, dist, criteria=CV_CRITERIA).reshape(-1, 2)
    xy = cam.undistort_points(uv)
    np.testing.assert_allclose(xy, xy_cv, atol=1e-7)
    # and it inverts the projection exactly (a tighter, OpenCV-independent check)
    np.testing.assert_allclose(xy, p[:, :2] / p[:, 2:], atol=1e-11)


@pytest.mark.parametrize("cam", [EUROC, RADTAN5])
def test_radtan_kernel_agrees_with_the_generic_newton(cam: PinholeRadtan) -> None:
    """The numba per-point Newton against the base class's vectorised one, far outside the image too;
    a NaN pixel stays NaN."""
    rng = np.random.default_rng(3)
    xy_d = np.concatenate([rng.uniform(-0.9, 0.9, (400, 2)), rng.uniform(-4.0, 4.0, (100, 2)),
                           [[np.nan, 0.1]]])
    kernel = cam._undistort_normalized(xy_d)
    generic = CameraModel._undistort_normalized(cam, xy_d)
    np.testing.assert_array_equal(np.isnan(kernel), np.isnan(generic))
    assert np.all(np.isnan(kernel[-1]))
    finite = np.isfinite(generic[:, 0])
    np.testing.assert_allclose(kernel[finite], generic[finite], atol=1e-12)


def test_fisheye_undistort_points_matches_cv2() -> None:
    p = _points_in_fov(FISHEYE, 500, 6, 85.0)
    uv = FISHEYE.project(p)
    xy_cv = cv2.fisheye.undistortPoints(
        uv.reshape(-1, 1, 2), FISHEYE.K, FISHEYE.distortion, criteria=CV_CRITERIA
    ).reshape(-1, 2)
    xy = FISHEYE.undistort_points(uv)
    np.testing.assert_allclose(xy, xy_cv, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(xy, p[:, :2] / p[:, 2:], rtol=1e-10, atol=1e-11)


@pytest.mark.parametrize("cam,max_angle", ALL)
def test_unproject_gives_rays_through_the_points(cam: CameraModel, max_angle: float) -> None:
    p = _points_in_fov(cam, 100, 7, max_angle)
    rays = cam.unproject(cam.project(p))
    assert rays.shape == (100, 3)
    np.testing.assert_array_equal(rays[:, 2], 1.0)
    np.testing.assert_allclose(rays * p[:, 2:], p, rtol=1e-9, atol=1e-9)


def test_shapes_are_kept_and_points_behind_are_nan() -> None:
    p = np.array([[[0.1, 0.2, 2.0], [0.0, 0.0, -1.0]]])
    uv = EUROC.project(p)
    assert uv.shape == (1, 2, 2)
    assert np.all(np.isfinite(uv[0, 0])) and np.all(np.isnan(uv[0, 1]))
    assert EUROC.project_jacobian(p).shape == (1, 2, 2, 3)
    assert EUROC.project(np.array([0.1, 0.2, 2.0])).shape == (2,)
    with pytest.raises(ValueError):
        EUROC.project(np.zeros((4, 2)))


@pytest.mark.parametrize("cam", [EUROC, RATIONAL])
def test_undistortion_maps_match_cv2_radtan(cam: CameraModel) -> None:
    K_new = np.array([[400.0, 0.0, 380.0], [0.0, 410.0, 250.0], [0.0, 0.0, 1.0]])
    size = (760, 500)
    mx, my = cam.undistortion_maps(K_new, size)
    cx, cy = cv2.initUndistortRectifyMap(cam.K, cam.distortion, np.eye(3), K_new, size, cv2.CV_32FC1)
    assert mx.shape == (500, 760) and mx.dtype == np.float32
    np.testing.assert_allclose(mx, cx, atol=2e-3)
    np.testing.assert_allclose(my, cy, atol=2e-3)


def test_undistortion_maps_match_cv2_fisheye() -> None:
    K_new = FISHEYE.K * np.array([[0.6], [0.6], [1.0]])
    K_new[0, 2], K_new[1, 2] = 255.5, 255.5
    mx, my = FISHEYE.undistortion_maps(K_new)
    cx, cy = cv2.fisheye.initUndistortRectifyMap(
        FISHEYE.K, FISHEYE.distortion, np.eye(3), K_new, FISHEYE.size, cv2.CV_32FC1
    )
    np.testing.assert_allclose(mx, cx, atol=2e-3)
    np.testing.assert_allclose(my, cy, atol=2e-3)


def test_undistorted_image_matches_pinhole_projection() -> None:
    """Remapping with our maps turns the distorted image of a point into its pinhole projection."""
    K_new = EUROC.K
    mx, my = EUROC.undistortion_maps()
    p = np.array([[-1.2, -0.7, 2.5]])  # towards the top-left corner, where distortion is strong
    u, v = EUROC.project(p)[0]
    img = np.zeros((EUROC.height, EUROC.width), np.float32)
    ui, vi = int(round(u)), int(round(v))
    img[vi - 2 : vi + 3, ui - 2 : ui + 3] = 1.0
    out = cv2.remap(img, mx, my, cv2.INTER_LINEAR)
    ys, xs = np.nonzero(out > 0.5)
    expected = EUROC.pinhole(K_new).project(p)[0]
    measured = np.array([xs.mean(), ys.mean()])  # centre of the remapped blob
    assert np.linalg.norm(measured - expected) < 2.5


@pytest.mark.parametrize("cam,max_angle", ALL)
def test_scaled_camera_follows_resized_pixels(cam: CameraModel, max_angle: float) -> None:
    p = _points_in_fov(cam, 50, 8, max_angle)
    sx, sy = 504 / cam.width, 0.5
    small = cam.scaled(sx, sy)
    assert small.size == (round(cam.width * sx), round(cam.height * sy))
    expected = (cam.project(p) + 0.5) * np.array([sx, sy]) - 0.5
    np.testing.assert_allclose(small.project(p), expected, atol=1e-9)
    resized = cam.resized(small.width, small.height)
    np.testing.assert_allclose(
        resized.project(p),
        (cam.project(p) + 0.5) * np.array([small.width / cam.width, small.height / cam.height]) - 0.5,
        atol=1e-9,
    )
    assert type(small) is type(cam)


def test_rectified_flags_and_pinhole() -> None:
    assert PINHOLE.is_pinhole_rectified
    assert PinholeRadtan(10, 10, 5, 5, 5, 5, [0, 0, 0, 0]).is_pinhole_rectified
    assert not EUROC.is_pinhole_rectified
    rect = EUROC.pinhole()
    assert isinstance(rect, Pinhole) and np.array_equal(rect.K, EUROC.K)
    assert EUROC.K[0, 0] == 458.654 and EUROC.K[1, 2] == 248.375 and EUROC.K[2, 2] == 1.0


def test_camera_class_names() -> None:
    assert camera_class("radtan") is PinholeRadtan
    assert camera_class("radial-tangential") is PinholeRadtan
    assert camera_class("rational") is camera_class("rational_polynomial") is PinholeRational
    for name in ("equidistant", "equi", "Fisheye"):
        assert camera_class(name) is PinholeEquidistant
    with pytest.raises(CalibrationError) as err:
        camera_class("omni")
    assert err.value.key == "distortion_model"


@pytest.mark.parametrize(
    "args,key",
    [
        ((752, 480, -458.0, 457.0, 367.0, 248.0, [0.0] * 4), "intrinsics"),
        ((752, 480, 458.0, 0.0, 367.0, 248.0, [0.0] * 4), "intrinsics"),
        ((752, 480, 458.0, 457.0, float("nan"), 248.0, [0.0] * 4), "intrinsics"),
        ((0, 480, 458.0, 457.0, 367.0, 248.0, [0.0] * 4), "resolution"),
        ((752.5, 480, 458.0, 457.0, 367.0, 248.0, [0.0] * 4), "resolution"),
        ((752, 480, 458.0, 457.0, 367.0, 248.0, [0.0] * 3), "distortion"),
        ((752, 480, 458.0, 457.0, 367.0, 248.0, [0.0] * 5, PinholeRational), "distortion"),
        ((752, 480, 458.0, 457.0, 367.0, 248.0, [0.0, float("inf"), 0.0, 0.0]), "distortion"),
        ((752, 480, 458.0, 457.0, 367.0, 248.0, ["a", 0.0, 0.0, 0.0]), "distortion"),
    ],
)
def test_invalid_camera_numbers_raise(args: tuple, key: str) -> None:
    cls = args[7] if len(args) > 7 else PinholeRadtan
    with pytest.raises(CalibrationError) as err:
        cls(*args[:7])
    assert err.value.key == key
    with pytest.raises(CalibrationError):
        PinholeEquidistant(752, 480, 458.0, 457.0, 367.0, 248.0, [0.0] * 5)


def test_isclose() -> None:
    same = PinholeRadtan(752, 480, 458.654, 457.296, 367.215, 248.375, EUROC.distortion.tolist())
    assert EUROC.isclose(same)
    assert not EUROC.isclose(EUROC.scaled(0.5, 0.5))
    assert not EUROC.isclose(
        PinholeEquidistant(752, 480, 458.654, 457.296, 367.215, 248.375, EUROC.distortion)
    )
