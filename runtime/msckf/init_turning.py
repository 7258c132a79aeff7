"""Turning-in-place initializer: the static initializer's rule for a body that turns about its IMU.

OpenVINS's static initializer (init_static) takes a quiet accelerometer and still images as proof that
the IMU stands still, and starts at zero velocity. A robot that turns on the spot at start-up fails its
image test: the features sweep across the image although the IMU does not move. This initializer applies
the same tests with the rotation removed, on a window of ``window_time_s`` split in two halves:

- the gyro turned the body by at least ``min_rotation_deg`` over the window (less is the static
  initializer's case, whose raw disparity test then passes);
- the tracks' disparity with the gyro's own rotation removed (first to last bearing in each half, in
  pixels; the gyro without the images' bias, which would absorb part of a translation's flow) is below
  ``max_disparity_px`` in each half, as OpenVINS's still images;
- the camera's rotation between neighbouring frames, fitted to the tracks' bearings (2-point RANSAC,
  Kabsch), gives the gyro bias (least squares over the frame pairs), which must lie within
  ``max_gyro_bias`` of zero;
- the specific force, rotated by the gyro into one frame, varies by less than ``init_imu_thresh`` in
  each half (OpenVINS's accelerometer 'std': a standing IMU sees the same gravity in every direction);
- the window turned far enough (``min_bias_turn_rad``) for the accelerometer bias across the turn axis
  to be told from gravity: a standing IMU reads gravity plus a bias that turns with the body.

The state: p = v = 0, gravity and the accelerometer bias from the rotated specific force (Gram-Schmidt
yaw, as the static initializer; the bias along the turn axis as OpenVINS's static one sets it), ``bg``
from the images, at the newest IMU sample no later than the newest frame of the window. What it cannot
tell: a camera that translates in front of a distant, flat scene while turning looks as still as
OpenVINS's static test lets a non-turning one look; the disparity threshold bounds the speed the same
way (in the tests' room, 2-7 m across: 0.15 m/s passes at 7.4 px, 0.2 m/s is refused at 10.1 px).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from runtime.config_checks import finite_fields, non_negative, positive
from runtime.errors import ConfigError
from runtime.geometry.so3 import so3_log
from runtime.geometry.two_view import bearings, rotation_ransac
from runtime.msckf.init_common import (
    BufferedInitializer,
    InitResult,
    accel_excitation,
    diagonal_cov,
    rotation_from_up,
)
from runtime.msckf.init_dynamic_excitation import gyro_rotation_deg
from runtime.msckf.init_turning_imu import gravity_and_accel_bias, gyro_orientations


@dataclass
class TurningInitConfig:
    """Turning-in-place initializer settings (the standstill thresholds are OpenVINS's static ones)."""

    enabled: bool = True
    """Arm it beside the static and dynamic initializers."""
    window_time_s: float = 2.0
    """Length of the two half-windows together, s (OpenVINS init_window_time)."""
    min_rotation_deg: float = 2.5
    """Gyro rotation over the window below which the body counts as not turning (the static
    initializer's case), deg: two halves of 10 px at 458 px focal."""
    init_imu_thresh: float = 1.5
    """Rotation-compensated specific-force 'std' separating still from moving, m/s^2 (OpenVINS)."""
    max_disparity_px: float = 10.0
    """Mean rotation-compensated track disparity per half above which the IMU counts as moving, px
    (OpenVINS init_max_disparity)."""
    min_bias_turn_rad: float = 0.3
    """How far the window must turn for the accelerometer bias across the turn axis to be estimated:
    the RMS angle by which the bias direction spreads over the window (sqrt of the second eigenvalue of
    the bias design, per sample), rad. A filter started without that bias component dead-reckons it
    while turning in place. Over 2 s windows of the rotation preset (BENCHMARKS "Starting while turning
    in place"), with a gyro bias 0.002 rad/s off (the images' error), the bias errs by 0.034 m/s^2
    (median; at most 0.046) at spreads of 0.3-0.4 rad, and by 0.065 (at most 0.090) at 0.15-0.2 rad; the
    simulator draws 0.05 per axis."""
    min_disparity_features: int = 15
    """Tracks needed in each half (OpenVINS 15)."""
    max_gyro_bias: float = 0.05
    """Largest gyro bias (norm) the images may attribute to the gyro, rad/s; beyond it the images
    disagree with a turn about the IMU (a translation read as rotation) and the window is refused."""
    min_pair_inliers: int = 20
    """A frame pair's rotation needs this many RANSAC inliers to enter the bias estimate."""
    ransac_threshold_px: float = 2.0
    """Inlier threshold of the rotation fit, px (angle x focal). The camera's lever arm moves near and far
    tracks apart by a pixel or so while turning; at 1 px the inlier set, and the bias with it, depended on
    the RANSAC draws (by 2e-4 rad/s on the synthetic turn of the tests), at 2 px it does not. Chosen with
    the rotation preset's seeds in view: at 1 px seed 1's window at 20 s published a wrong start (0.66 m),
    at 2 px it drifts to 0.40 m (BENCHMARKS "Starting while turning in place")."""
    max_imu_gap_s: float = 0.05
    """A window with a longer gap between IMU samples is refused (its rotations would be guessed), s."""
    gravity_mag: float = 9.81
    """Gravity magnitude g0, m/s^2."""
    sigma_theta: float = 0.02
    """Initial orientation std, rad (as the static initializer)."""
    sigma_p: float = 0.05
    """Initial position std, m."""
    sigma_v: float = 0.01
    """Initial velocity std, m/s."""
    sigma_bg: float = 0.02
    """Initial gyro bias std, rad/s (the camera's lever arm biases the image estimate by about
    |w x p_IC| / depth: 0.014 rad/s at 0.6 rad/s, 7 cm, 3 m)."""
    sigma_ba: float = 0.02
    """Initial accelerometer bias std, m/s^2."""

    def __post_init__(self) -> None:
        finite_fields(self, "turning_init", allow_inf=("max_disparity_px", "max_gyro_bias", "max_imu_gap_s"))
        positive(self, "turning_init", "sigma_theta", "sigma_p", "sigma_v", "sigma_bg", "sigma_ba")
        non_negative(self, "turning_init", "min_rotation_deg")
        if not self.window_time_s > 0:
            raise ConfigError(f"turning_init.window_time_s must be > 0 s, got {self.window_time_s}")
        for name in ("init_imu_thresh", "max_disparity_px", "max_gyro_bias", "ransac_threshold_px",
                     "max_imu_gap_s", "gravity_mag"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"turning_init.{name} must be > 0, got {getattr(self, name)}")
        if not self.min_bias_turn_rad >= 0:
            raise ConfigError(f"turning_init.min_bias_turn_rad must be >= 0, got {self.min_bias_turn_rad}")
        if self.min_disparity_features < 1 or self.min_pair_inliers < 3:
            raise ConfigError("turning_init.min_disparity_features must be >= 1 and min_pair_inliers >= 3")


class TurningInitializer(BufferedInitializer):
    """Initialize the filter at zero velocity while the body turns about its IMU (module docstring).

    Args:
        camera: calib camera model (undistort_points, fx, fy).
        T_IC: (4, 4) camera pose in the IMU frame.
        config: settings (TurningInitConfig() if None).
        imu_noise: accepted for a uniform initializer interface.
        time_offset_s: camera-to-IMU clock offset, s (t_imu = t_cam + offset).
    """

    source = "turning"

    def __init__(self, camera: object, T_IC: np.ndarray, config: TurningInitConfig | None = None,
                 imu_noise: object | None = None, time_offset_s: float = 0.0) -> None:
        self.config = config if config is not None else TurningInitConfig()
        self.camera = camera
        self.R_IC = np.asarray(T_IC, dtype=np.float64)[:3, :3].copy()
        self.focal = 0.5 * (float(camera.fx) + float(camera.fy))
        self.time_offset_ns = int(round(float(time_offset_s) * 1e9))
        self.imu_noise = imu_noise
        self.window_ns = int(round(self.config.window_time_s * 1e9))
        self._init_buffers(self.window_ns + 400_000_000, camera)
        self._pair_cache: dict[tuple[int, int], np.ndarray | None] = {}
        self.accepted: dict | None = None
        """The diagnostics of the last accepted window (rotation, bias, excitation, disparities)."""

    def reset(self) -> None:
        """Forget buffered IMU samples, tracks and pair rotations (after a filter reset); counts are kept."""
        super().reset()
        self._pair_cache.clear()
        self.accepted = None

    def report(self) -> dict:
        """Counters for the run report, with the last accepted window's diagnostics."""
        return {**super().report(), "accepted": self.accepted}

    # ------------------------------------------------------------------ decision
    def try_initialize(self) -> InitResult | None:
        """An InitResult when the window passes the tests, else None (reason in last_reason)."""
        cfg = self.config
        rej = self.log.reject
        t, w, a = self.imu.arrays()
        if t.size < 2 or not self.tracks.frames:
            return rej(-1 if t.size == 0 else int(t[-1]), "no_data", "no IMU samples or no frames yet")
        off = self.time_offset_ns
        frames = [f for f in self.tracks.frames if f[0] + off <= int(t[-1])]
        if not frames:
            return rej(int(t[-1]), "no_data", "no frame covered by the IMU yet")
        t_end = frames[-1][0] + off                         # IMU clock
        t_start = t_end - self.window_ns
        if int(t[0]) > t_start:
            span = max((t_end - int(t[0])) * 1e-9, 0.0)
            return rej(t_end, "short_window",
                       f"{span:.2f} s of IMU before the newest frame < {cfg.window_time_s} s")
        frames = [f for f in frames if f[0] + off >= t_start]
        keep = (t >= t_start) & (t <= t_end)
        t, w, a = t[keep], w[keep], a[keep]
        if t.size < 4 or len(frames) < 4:
            return rej(t_end, "short_window", "fewer than 4 IMU samples or frames in the window")
        gap = float(np.max(np.diff(t))) * 1e-9
        if gap > cfg.max_imu_gap_s:
            return rej(t_end, "imu_gap",
                       f"{gap:.3f} s without an IMU sample in the window > {cfg.max_imu_gap_s} s")

        zero = np.zeros(3)
        turned = gyro_rotation_deg(t, w, int(t[0]), int(t[-1]), zero)     # path length: no wrap at pi
        if turned < cfg.min_rotation_deg:
            return rej(t_end, "not_turning", f"gyro turned {turned:.2f} deg < {cfg.min_rotation_deg} deg")

        half = t_start + self.window_ns // 2
        old, new = t <= half, t > half
        if old.sum() < 2 or new.sum() < 2:
            return rej(t_end, "short_window", "fewer than 2 IMU samples in a half-window")
        # the frames' orientations from the gyro alone, shared by the disparity test and the bias fit
        R_0f = gyro_orientations(t, w, zero, np.array([f[0] + off for f in frames], dtype=np.int64))
        disp = []
        for lo, hi in ((t_start, half), (half, t_end)):
            d, n = self._derotated_disparity(frames, lo - off, hi - off, R_0f)
            if n < cfg.min_disparity_features:
                return rej(t_end, "few_features", f"{n} half-window tracks < {cfg.min_disparity_features}")
            disp.append(d)
        info = {"rotation_deg": turned, "disparity_old_px": disp[0], "disparity_new_px": disp[1]}
        if max(disp) > cfg.max_disparity_px:
            return rej(t_end, "moving", f"rotation-compensated disparity {disp[0]:.2f}, {disp[1]:.2f} "
                       f"> {cfg.max_disparity_px} px (the IMU translates)")

        bg, n_pairs = self._visual_gyro_bias(frames, R_0f)
        if bg is None:
            return rej(t_end, "no_visual_rotation", f"{n_pairs} frame pairs with a rotation fit < 2")
        info.update(bg_visual=bg.copy(), visual_pairs=n_pairs)
        if float(np.linalg.norm(bg)) > cfg.max_gyro_bias:
            return rej(t_end, "gyro_bias_too_large", f"images attribute {np.linalg.norm(bg):.3f} rad/s "
                       f"to the gyro bias > {cfg.max_gyro_bias}")

        R_0k = gyro_orientations(t, w, bg, t)               # R_{I0 Ik} at every sample
        f_end = np.einsum("ij,kjl,kl->ki", R_0k[-1].T, R_0k, a)   # specific force in I(t_end)
        exc = [accel_excitation(f_end[m]) for m in (old, new)]
        info.update(accel_excitation_old=exc[0], accel_excitation_new=exc[1])
        if max(exc) > cfg.init_imu_thresh:
            return rej(t_end, "moving", f"rotation-compensated excitation {exc[0]:.3f}, {exc[1]:.3f} "
                       f"> {cfg.init_imu_thresh} m/s^2 (the IMU accelerates)")

        up, ba, spread = gravity_and_accel_bias(R_0k, a, cfg.gravity_mag)
        info.update(bias_turn_spread_rad=spread, ba=ba.copy())
        if spread < cfg.min_bias_turn_rad:
            return rej(t_end, "bias_unobservable", f"the turn's spread {spread:.3f} rad < "
                       f"{cfg.min_bias_turn_rad} rad: the accelerometer bias across the turn axis cannot "
                       "be told from gravity yet")
        if not (np.isfinite(up).all() and np.linalg.norm(up) > 0.0):
            return rej(t_end, "accel_magnitude", "no gravity direction in the specific force (an "
                       "accelerometer reading zero)")
        R_OI = rotation_from_up(up)
        cov = diagonal_cov((cfg.sigma_theta, cfg.sigma_p, cfg.sigma_v, cfg.sigma_bg, cfg.sigma_ba))
        info["n_samples"] = int(t.size)
        self.accepted = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in info.items()}
        return InitResult(t_ns=int(t[-1]), R_OI=R_OI, p_OI=np.zeros(3), v_OI=np.zeros(3), bg=bg, ba=ba,
                          cov=cov, source=self.source, info=info)

    # ------------------------------------------------------------------ helpers
    def _pair_rotation(self, fa: tuple, fb: tuple) -> np.ndarray | None:
        """R_{Cb Ca} fitted to the common tracks of two frames (cached: it does not depend on the bias)."""
        key = (fa[0], fb[0])
        if key in self._pair_cache:
            return self._pair_cache[key]
        _, ids_a, _, xy_a = fa
        _, ids_b, _, xy_b = fb
        _, ia, ib = np.intersect1d(ids_a, ids_b, return_indices=True)
        R = None
        if ia.size >= self.config.min_pair_inliers:
            pa, pb = xy_a[ia], xy_b[ib]
            ok = np.all(np.isfinite(pa), axis=1) & np.all(np.isfinite(pb), axis=1)
            if ok.sum() >= self.config.min_pair_inliers:
                thr = self.config.ransac_threshold_px / self.focal
                rng = np.random.default_rng((fa[0] % 2**32, fb[0] % 2**32))   # the pair's own draws
                R_ba, inl = rotation_ransac(bearings(pa[ok]), bearings(pb[ok]), thr, rng)
                if inl.sum() >= self.config.min_pair_inliers:
                    R = R_ba
        if len(self._pair_cache) > 4096:
            self._pair_cache.clear()
        self._pair_cache[key] = R
        return R

    def _visual_gyro_bias(self, frames: list, R_0f: np.ndarray) -> tuple[np.ndarray | None, int]:
        """Least-squares gyro bias making the gyro's rotation between neighbouring frames (R_0f (k, 3, 3):
        the frames' orientations from the gyro without bias) the images'."""
        num, den, n = np.zeros(3), 0.0, 0
        for k in range(len(frames) - 1):
            R_cam = self._pair_rotation(frames[k], frames[k + 1])
            if R_cam is None:
                continue
            R_vis = self.R_IC @ R_cam.T @ self.R_IC.T       # R_{Ik Ik+1} as the images see it
            R_gyr = R_0f[k].T @ R_0f[k + 1]
            dt = (frames[k + 1][0] - frames[k][0]) * 1e-9
            # R_gyr(bg) ~ R_gyr(0) Exp(-bg dt) = R_vis  =>  bg dt = -Log(R_gyr^T R_vis)
            num += -so3_log(R_gyr.T @ R_vis) * dt
            den += dt * dt
            n += 1
        if n < 2:
            return None, n
        return num / den, n

    def _derotated_disparity(self, frames: list, t0_cam: int, t1_cam: int,
                             R_0f: np.ndarray) -> tuple[float, int]:
        """Mean angle (px) between each track's last bearing and its first one rotated by the gyro (R_0f
        (k, 3, 3): the frames' orientations), over the frames in [t0_cam, t1_cam] (camera clock); and the
        number of tracks."""
        sel = [k for k, f in enumerate(frames) if t0_cam <= f[0] <= t1_cam]
        if len(sel) < 2:
            return 0.0, 0
        ids = np.concatenate([frames[k][1] for k in sel])
        xy = np.concatenate([frames[k][3] for k in sel])
        kk = np.concatenate([np.full(frames[k][1].shape[0], k) for k in sel])
        ok = np.all(np.isfinite(xy), axis=1)
        ids, xy, kk = ids[ok], xy[ok], kk[ok]
        order = np.lexsort((kk, ids))                       # by track, then frame
        ids, xy, kk = ids[order], xy[order], kk[order]
        _, first, counts = np.unique(ids, return_index=True, return_counts=True)
        seen_twice = counts >= 2
        if not seen_twice.any():
            return 0.0, 0
        a = first[seen_twice]
        b = a + counts[seen_twice] - 1
        # bearing of view a expressed in camera b: R_CbCa = R_CI R_0b^T R_0a R_IC
        R_ba = np.einsum("ij,kjl,klm,mn->kin", self.R_IC.T, np.transpose(R_0f[kk[b]], (0, 2, 1)),
                         R_0f[kk[a]], self.R_IC)
        rot = np.einsum("kij,kj->ki", R_ba, bearings(xy[a]))
        bb = bearings(xy[b])
        ang = np.arctan2(np.linalg.norm(np.cross(rot, bb), axis=1), np.einsum("ij,ij->i", rot, bb))
        return float(self.focal * ang.mean()), int(a.size)
