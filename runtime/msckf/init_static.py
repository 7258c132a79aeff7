"""Static initializer (OpenVINS ``StaticInitializer`` logic): stand still, then a jerk.

Decision, on a window of ``init_window_time_s`` ending at the newest IMU sample, split in an
older half and a newer half:

- accelerometer excitation of each half = sqrt(sum |a - mean|^2 / (n - 1)) (m/s^2);
- ``wait_for_jerk`` (OpenVINS without a zero-velocity update): the newer half must be above
  ``init_imu_thresh`` (a jerk) and the older half below it (standing still before the jerk);
- otherwise: both halves must be below the threshold (standing still);
- when tracks are fed and ``init_max_disparity_px > 0``, the mean feature disparity of each half
  (tracks' first-to-last pixel motion within the half, relative to the newest frame time) must
  agree: a jerk needs a still older half and a moving newer half; standing still needs both still.

The state is taken from the older (still) half: orientation from the mean accelerometer (Gram-
Schmidt, deterministic yaw), ``bg`` = mean gyro, ``ba`` = mean accel - R_IO (0, 0, g0) (as
OpenVINS: the accelerometer's excess along gravity), p = v = 0, time = last sample of that half.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from runtime.config_checks import finite_fields, positive
from runtime.errors import ConfigError
from runtime.msckf.init_common import (
    BufferedInitializer,
    InitResult,
    accel_excitation,
    diagonal_cov,
    rotation_from_up,
)


@dataclass
class StaticInitConfig:
    """Static initializer settings (defaults: OpenVINS EuRoC)."""

    init_window_time_s: float = 2.0
    """Length of the two half-windows together, s (OpenVINS init_window_time)."""
    init_imu_thresh: float = 1.5
    """Accelerometer excitation (sample std of the vector) separating still from moving, m/s^2."""
    init_max_disparity_px: float = 10.0
    """Mean track disparity above which a half-window counts as moving, px (<= 0: not used)."""
    min_disparity_features: int = 15
    """Tracks needed in each half-window to judge disparity (OpenVINS 15)."""
    wait_for_jerk: bool | None = None
    """Initialize on a jerk after standing still (True) or as soon as still (False). None: as OpenVINS,
    wait for a jerk only when the filter has no zero-velocity update to hold a standing start (the
    pipeline resolves it from MsckfConfig.try_zupt; a StaticInitializer given None waits for the jerk)."""
    gravity_mag: float = 9.81
    """Gravity magnitude g0, m/s^2."""
    sigma_theta: float = 0.02
    """Initial orientation std, rad (OpenVINS 0.02)."""
    sigma_p: float = 0.05
    """Initial position std, m (OpenVINS 0.05)."""
    sigma_v: float = 0.01
    """Initial velocity std, m/s (OpenVINS 0.01)."""
    sigma_bg: float = 0.02
    """Initial gyro bias std, rad/s (OpenVINS 0.02)."""
    sigma_ba: float = 0.02
    """Initial accelerometer bias std, m/s^2 (OpenVINS 0.02)."""

    def __post_init__(self) -> None:
        finite_fields(self, "static_init")
        positive(self, "static_init", "sigma_theta", "sigma_p", "sigma_v", "sigma_bg", "sigma_ba")
        if not self.init_window_time_s > 0:
            raise ConfigError(f"static init window must be > 0 s, got {self.init_window_time_s}")
        if not self.init_imu_thresh > 0:
            raise ConfigError(f"static init_imu_thresh must be > 0, got {self.init_imu_thresh}")
        if not self.gravity_mag > 0:
            raise ConfigError(f"gravity_mag must be > 0, got {self.gravity_mag}")
        if self.min_disparity_features < 1:
            raise ConfigError(f"min_disparity_features must be >= 1, got {self.min_disparity_features}")


class StaticInitializer(BufferedInitializer):
    """Initialize the filter state from a stand-still period (then, by default, a jerk).

    Args:
        config: settings (StaticInitConfig() if None).
        imu_noise: calib.ImuNoise, accepted for a uniform initializer interface (the static
            decision uses the threshold only).
    """

    source = "static"

    def __init__(self, config: StaticInitConfig | None = None, imu_noise: object | None = None) -> None:
        self.config = config if config is not None else StaticInitConfig()
        self.wait_for_jerk = self.config.wait_for_jerk is not False
        """The jerk rule in force (StaticInitConfig.wait_for_jerk, None read as True)."""
        self.imu_noise = imu_noise
        window_ns = int(round(self.config.init_window_time_s * 1e9))
        self._init_buffers(window_ns + 200_000_000)

    def try_initialize(self) -> InitResult | None:
        """An InitResult when the window passes the checks, else None (reason in last_reason)."""
        cfg = self.config
        rej = self.log.reject
        t, w, a = self.imu.arrays()
        if t.size < 2:
            return self.log.reject(-1 if t.size == 0 else int(t[-1]), "no_imu", "fewer than 2 IMU samples")
        newest = int(t[-1])
        window_ns = int(round(cfg.init_window_time_s * 1e9))
        if newest - int(t[0]) < window_ns:
            return rej(newest, "short_window",
                       f"{(newest - t[0]) * 1e-9:.2f} s of IMU < {cfg.init_window_time_s} s")
        half_ns = window_ns // 2
        new_half = (t > newest - half_ns) & (t <= newest)
        old_half = (t > newest - window_ns) & (t <= newest - half_ns)
        if new_half.sum() < 2 or old_half.sum() < 2:
            return rej(newest, "short_window", "fewer than 2 IMU samples in a half-window")
        std_new = accel_excitation(a[new_half])
        std_old = accel_excitation(a[old_half])
        thr = cfg.init_imu_thresh
        info = {"accel_excitation_old": std_old, "accel_excitation_new": std_new}

        if self.wait_for_jerk:
            if std_new < thr:
                return rej(newest, "no_jerk", f"newest half excitation {std_new:.3f} < {thr} m/s^2")
            if std_old > thr:
                return rej(newest, "moving", f"older half excitation {std_old:.3f} > {thr} m/s^2 (not still)")
        elif std_new > thr or std_old > thr:
            return rej(newest, "moving",
                       f"excitation {std_old:.3f}, {std_new:.3f} > {thr} m/s^2 (not standing still)")

        if cfg.init_max_disparity_px > 0 and self.tracks.newest_ns is not None:
            dmax = cfg.init_max_disparity_px
            cam_newest = self.tracks.newest_ns
            cam_half = cam_newest - half_ns
            disp_old, n_old = self.tracks.disparity(cam_newest - window_ns, cam_half)
            disp_new, n_new = self.tracks.disparity(cam_half, cam_newest)
            info.update(disparity_old_px=disp_old, disparity_new_px=disp_new)
            if min(n_old, n_new) < cfg.min_disparity_features:
                return rej(newest, "few_features",
                           f"{n_old}, {n_new} half-window tracks < {cfg.min_disparity_features}")
            moving_old = disp_old > dmax
            moving_new = disp_new > dmax
            if moving_old:
                return rej(newest, "moving", f"older half disparity {disp_old:.2f} > {dmax} px")
            if self.wait_for_jerk and not moving_new:
                return rej(newest, "no_visual_jerk", f"newest half disparity {disp_new:.2f} <= {dmax} px")
            if not self.wait_for_jerk and moving_new:
                return rej(newest, "moving", f"newest half disparity {disp_new:.2f} > {dmax} px")

        a_mean = a[old_half].mean(axis=0)
        g_meas = float(np.linalg.norm(a_mean))
        if not 0.5 * cfg.gravity_mag <= g_meas <= 1.5 * cfg.gravity_mag:
            return rej(newest, "accel_magnitude",
                       f"mean specific force {g_meas:.2f} m/s^2 at rest is not gravity's "
                       f"{cfg.gravity_mag:.2f} (an accelerometer reading zero or saturated, or not in m/s^2)")
        R_OI = rotation_from_up(a_mean)
        ba = a_mean - R_OI.T @ np.array([0.0, 0.0, cfg.gravity_mag])
        bg = w[old_half].mean(axis=0)
        cov = diagonal_cov((cfg.sigma_theta, cfg.sigma_p, cfg.sigma_v, cfg.sigma_bg, cfg.sigma_ba))
        info["n_samples"] = int(old_half.sum())
        return InitResult(t_ns=int(t[old_half][-1]), R_OI=R_OI, p_OI=np.zeros(3), v_OI=np.zeros(3),
                          bg=bg, ba=ba, cov=cov, source=self.source, info=info)
