"""Dynamic initializer: linear visual-inertial solve under |g| = g0, then a nonlinear refinement.

Following the idea of OpenVINS' ``DynamicInitializer`` (Dong-Si & Mourikis, ICRA 2012, Eq. 14);
:class:`DynamicInitializer` runs the stages and rejects (with a reason code) where one fails:

1. Keyframes: ``num_pose`` frames spread evenly over the last ``init_window_time_s``; features
   seen in at least ``min_feature_observations`` of them (longest first, ``max_features``)
   (init_dynamic_window). Codes: no_frames, few_frames, short_window, few_features, imu_gap.
2. Excitation: integrated gyro rotation and median rotation-compensated parallax
   (init_dynamic_excitation). Codes: insufficient_rotation, insufficient_parallax.
3. Rotations from gyro preintegration (init_dynamic_preintegration) at the bias prior, or at the
   bias that aligns them with essential-matrix rotations (init_dynamic_gyro_bias). After the
   parallax check (2), the rotations at the bias prior are checked against the camera's two-view
   rotations between keyframes, after a clean check only every `rotation_check_interval_s`
   (init_dynamic_rotation_check; not in OpenVINS; code: rotation_mismatch, after which attempts wait
   `rotation_mismatch_retry_s`).
4. Linear solve for features, v0 and g with |g| = g0 in the first keyframe's IMU frame I0, then
   the gravity-aligned frame O: I0 rotated so that g = (0, 0, -g0), yaw fixed by Gram-Schmidt,
   origin at I0 (init_dynamic_linear). Codes: degenerate, bad_linear_solution.
5. Refinement of keyframe states, biases and features, and the newest state's inflated
   covariance (init_dynamic_refinement). Codes: mle_failed (no finite solution, or the reprojection RMS
   too high), mle_not_converged (within mle_max_iterations), implausible_bias.

Re-exported for callers: :class:`DynamicInitConfig`, :class:`LinearSolution`, :func:`min_quadratic_on_sphere`.
"""

from __future__ import annotations

import math
from functools import partial

import numpy as np

from runtime.errors import ConfigError, DataError
from runtime.msckf.init_common import BufferedInitializer, InitResult
from runtime.msckf.init_dynamic_config import DynamicInitConfig
from runtime.msckf.init_dynamic_excitation import gyro_rotation_deg, median_parallax_deg
from runtime.msckf.init_dynamic_gyro_bias import visual_gyro_bias
from runtime.msckf.init_dynamic_linear import (
    LinearSolution,
    in_front_of_first_camera,
    min_quadratic_on_sphere,
    solve_linear,
    states_in_gravity_frame,
)
from runtime.msckf.init_dynamic_preintegration import preintegrate_keyframes
from runtime.msckf.init_dynamic_refinement import WindowRefinement
from runtime.msckf.init_dynamic_rotation_check import rotation_agreement
from runtime.msckf.init_dynamic_window import (
    Frame,
    frames_in_window,
    keep_features,
    pick_keyframes,
    select_features,
)

__all__ = ["DynamicInitConfig", "DynamicInitializer", "LinearSolution", "min_quadratic_on_sphere"]

# continuous-time noise densities used when no calib.ImuNoise is given (EuRoC / OpenVINS values)
_DEFAULT_GYRO_DENSITY = 1.6968e-4
_DEFAULT_ACCEL_DENSITY = 2.0e-3


def _density(imu_noise: object, name: str, default: float) -> float:
    """A noise density of the rig's IMU; the default only when it is withheld (None), never for 0."""
    v = getattr(imu_noise, name, None)
    if v is None:
        return default
    v = float(v)
    if not (math.isfinite(v) and v > 0):
        raise ConfigError(f"IMU {name} must be finite and positive, got {v!r}")
    return v


class DynamicInitializer(BufferedInitializer):
    """Initialize while moving from tracked features and IMU over a short window.

    Args:
        camera: calib.CameraModel of the tracked images (used to undistort the pixels fed).
        T_IC: (4, 4) camera pose in the IMU frame (x_I = T_IC x_C).
        config: settings (DynamicInitConfig() if None).
        imu_noise: calib.ImuNoise (continuous noise densities); EuRoC values if None.
        time_offset_s: t_imu = t_cam + time_offset_s (Kalibr timeshift_cam_imu).
    """

    source = "dynamic"

    def __init__(
        self,
        camera: object,
        T_IC: np.ndarray,
        config: DynamicInitConfig | None = None,
        imu_noise: object | None = None,
        time_offset_s: float = 0.0,
    ) -> None:
        self.camera = camera
        T = np.asarray(T_IC, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ConfigError(f"T_IC must be a finite 4x4 matrix, got shape {T.shape}")
        self.R_IC = T[:3, :3].copy()
        self.p_IC = T[:3, 3].copy()
        self.config = config if config is not None else DynamicInitConfig()
        self.gyro_density = _density(imu_noise, "gyro_noise_density", _DEFAULT_GYRO_DENSITY)
        self.accel_density = _density(imu_noise, "accel_noise_density", _DEFAULT_ACCEL_DENSITY)
        self.time_offset_ns = int(round(float(time_offset_s) * 1e9))
        self._init_buffers(self.config.window_ns + 500_000_000, camera)
        self.focal = 0.5 * (float(camera.fx) + float(camera.fy))
        self._retry_after_ns: int | None = None    # camera t_ns before which no attempt is made
        self._clean_ns: int | None = None          # camera t_ns of the last check no pair disagreed with
        #: the rotation checks so far: how many, refused, the largest share of disagreeing pairs and the
        #: largest median camera-gyro difference (deg) of a check (how close a rig came to the bound)
        self.rotation_check = {"checks": 0, "refused": 0, "max_disagreeing_share": 0.0,
                               "max_median_deg": 0.0}

    def reset(self) -> None:
        """Forget buffered IMU and tracks and any wait after a rotation_mismatch (counts are kept)."""
        super().reset()
        self._retry_after_ns = self._clean_ns = None

    def report(self) -> dict:
        """Counters for the run report, with the rotation checks'."""
        return {**super().report(), "rotation_check": dict(self.rotation_check)}

    # ------------------------------------------------------------------ main entry
    def try_initialize(self) -> InitResult | None:
        """An InitResult at the newest keyframe (IMU clock), or None (reason in last_reason)."""
        frames = list(self.tracks.frames)
        if not frames:
            return self.log.reject(-1, "no_frames", "no tracks fed")
        frames = frames_in_window(frames, self.imu.newest_ns(), self.time_offset_ns, self.config.window_ns)
        if frames and self._retry_after_ns is not None and frames[-1][0] < self._retry_after_ns:
            return None      # after a rotation_mismatch: the window slides first (last_reason kept)
        try:
            return self._initialize(frames)
        except _Rejected as why:
            return self.log.reject(frames[-1][0], why.code, why.message)

    def _initialize(self, frames: list[Frame]) -> InitResult:
        """The stages on the window's frames; raises _Rejected where one fails."""
        cfg = self.config
        if len(frames) < cfg.num_pose:
            raise _Rejected("few_frames", f"{len(frames)} frames in the window < num_pose {cfg.num_pose}")
        keyframes = pick_keyframes(frames, cfg.num_pose)
        t_cam = np.array([k[0] for k in keyframes], dtype=np.int64)
        if (t_cam[-1] - t_cam[0]) < cfg.min_window_fraction * cfg.window_ns:
            raise _Rejected(
                "short_window",
                f"keyframes span {(t_cam[-1] - t_cam[0]) * 1e-9:.2f} s "
                f"< {cfg.min_window_fraction} x the {cfg.init_window_time_s} s window",
            )
        t_imu = t_cam + self.time_offset_ns
        feat_ids, obs = select_features(keyframes, cfg.min_feature_observations, cfg.max_features)
        if feat_ids.size < cfg.min_features:
            raise _Rejected(
                "few_features",
                f"{feat_ids.size} features seen in >= {cfg.min_feature_observations} keyframes "
                f"< {cfg.min_features}",
            )
        ti, gyro, accel = self.imu.arrays()
        if ti.size < 2 or ti[0] > t_imu[0] or ti[-1] < t_imu[-1]:
            raise _Rejected("imu_gap", "the IMU buffer does not cover the keyframes")
        bg0 = np.asarray(cfg.bias_g_prior, dtype=np.float64)
        ba0 = np.asarray(cfg.bias_a_prior, dtype=np.float64)
        rot_deg = gyro_rotation_deg(ti, gyro, t_imu[0], t_imu[-1], bg0)
        if rot_deg < cfg.min_deg:
            raise _Rejected(
                "insufficient_rotation",
                f"gyro rotation {rot_deg:.2f} deg < {cfg.min_deg} deg over the window",
            )

        preintegrate = partial(
            preintegrate_keyframes, ti, gyro, accel, t_imu, ba=ba0,
            gyro_density=self.gyro_density, accel_density=self.accel_density,
        )
        try:
            imu = at_prior = preintegrate(bg=bg0)
            bg_visual = None
            if cfg.estimate_gyro_bias:
                bg_visual = visual_gyro_bias(
                    keyframes, imu.between, bg0, self.R_IC, self.focal, 2 * cfg.min_features,
                    cfg.max_visual_gyro_residual_rad,
                )
                if bg_visual is not None:
                    bg0 = bg_visual
                    imu = preintegrate(bg=bg0)
        except DataError as exc:
            raise _Rejected("imu_gap", f"preintegration failed: {exc}") from exc

        parallax = median_parallax_deg(obs, imu.R_0k, self.R_IC)
        if parallax < cfg.min_parallax_deg:
            raise _Rejected(
                "insufficient_parallax",
                f"median rotation-compensated parallax {parallax:.3f} deg < {cfg.min_parallax_deg} deg",
            )
        # past the parallax check (a wrong rig's rotation compensation leaves parallax) and at the bias prior
        self._check_rotations(keyframes, at_prior.between, ti, gyro)
        lin = solve_linear(
            obs, feat_ids.size, imu.R_0k, imu.dt_0k, imu.dp_0k, self.R_IC, self.p_IC,
            cfg.gravity_mag, cfg.min_features, cfg.max_feature_condition,
        )
        if lin.n_good < cfg.min_features:
            raise _Rejected(
                "degenerate", f"only {lin.n_good} features with depth information < {cfg.min_features}"
            )
        if not np.isfinite(lin.condition) or lin.condition > cfg.max_condition:
            raise _Rejected(
                "degenerate", f"velocity block condition {lin.condition:.3g} > {cfg.max_condition:.3g}"
            )
        usable, in_front = in_front_of_first_camera(lin.p_f, self.R_IC, self.p_IC)
        if in_front < cfg.min_positive_depth_fraction:
            raise _Rejected(
                "bad_linear_solution", f"only {in_front:.0%} of the features lie in front of the camera"
            )
        if usable.sum() < cfg.min_features:
            raise _Rejected("degenerate", f"only {int(usable.sum())} features in front of the camera")
        obs = keep_features(obs, usable)
        lin.p_f = lin.p_f[usable]

        R_k, p_k, v_k, p_f = states_in_gravity_frame(lin, imu.R_0k, imu.dt_0k, imu.dp_0k, imu.dv_0k)
        info = dict(
            linear_cost=lin.cost, condition=lin.condition, parallax_deg=parallax, rotation_deg=rot_deg,
            bg_visual=None if bg_visual is None else bg_visual.copy(), n_features=int(usable.sum()),
            n_keyframes=len(keyframes), g_I0_linear=lin.g_I0.copy(), v_I0_linear=lin.v_I0.copy(),
        )
        g_O = np.array([0.0, 0.0, -cfg.gravity_mag])
        refinement = WindowRefinement(obs, imu.between, g_O, bg0, ba0, self.R_IC, self.p_IC, self.focal, cfg)
        refined = refinement.run(R_k, p_k, v_k, p_f)
        if refined is None:
            raise _Rejected("mle_failed", "refinement gave no finite solution or covariance")
        info.update(reprojection_rms_px=refined.rms_px, mle_evaluations=refined.n_evaluations,
                    mle_converged=refined.converged)
        if not refined.converged:
            # as OpenVINS refuses a Ceres solve that did not end in CONVERGENCE; on fast motion such a
            # window can sit far from the truth at a small reprojection error (BENCHMARKS.md)
            n = refined.n_evaluations
            why = (f"did not converge in {n} evaluations (mle_max_iterations {cfg.mle_max_iterations})"
                   if n >= cfg.mle_max_iterations else
                   f"stopped without converging after {n} evaluations (no step lowered the cost, or the "
                   "Jacobian was not finite)")
            raise _Rejected("mle_not_converged", f"refinement {why}")
        if refined.rms_px > cfg.max_reprojection_rms_px:
            raise _Rejected(
                "mle_failed",
                f"reprojection RMS {refined.rms_px:.2f} px > {cfg.max_reprojection_rms_px} px "
                "after refinement",
            )
        ba_change = float(np.linalg.norm(refined.ba - ba0))
        if ba_change > cfg.max_accel_bias_change:
            raise _Rejected(
                "implausible_bias",
                f"accelerometer bias {ba_change:.2f} m/s^2 from the prior > {cfg.max_accel_bias_change}",
            )
        return InitResult(
            t_ns=int(t_imu[-1]), R_OI=refined.R_OI[-1], p_OI=refined.p_OI[-1], v_OI=refined.v_OI[-1],
            bg=refined.bg, ba=refined.ba, cov=refined.cov, source=self.source, info=info,
        )

    def _check_rotations(self, keyframes: list[Frame], between: list, imu_t_ns: np.ndarray,
                         gyro: np.ndarray) -> None:
        """Raise rotation_mismatch when the camera's keyframe rotations contradict the gyro's
        (runtime.msckf.init_dynamic_rotation_check)."""
        cfg = self.config
        t_ns = int(keyframes[-1][0])
        interval_ns = cfg.rotation_check_interval_s * 1e9
        if cfg.max_rotation_mismatch_fraction >= 1.0 or (
                self._clean_ns is not None and t_ns - self._clean_ns < interval_ns):
            return
        agree = rotation_agreement(keyframes, between, imu_t_ns, gyro, self.R_IC, self.focal,
                                   2 * cfg.min_features,
                                   cfg.max_visual_gyro_residual_rad, cfg.rotation_check_max_ratio,
                                   np.radians(cfg.rotation_check_min_gyro_deg))
        if agree.measured < cfg.min_rotation_check_pairs:
            return
        if agree.disagreeing == 0:
            self._clean_ns = t_ns
        rc = self.rotation_check
        rc["checks"] += 1
        rc["max_disagreeing_share"] = max(rc["max_disagreeing_share"], agree.disagreeing / agree.measured)
        rc["max_median_deg"] = max(rc["max_median_deg"], float(np.degrees(agree.median_rad)))
        if agree.disagreeing <= cfg.max_rotation_mismatch_fraction * agree.measured:
            return
        rc["refused"] += 1
        self._retry_after_ns = t_ns + int(round(cfg.rotation_mismatch_retry_s * 1e9))
        pairs = f"in {agree.disagreeing} of {agree.measured} keyframe pairs"
        if agree.gyro_scale >= agree.axis:
            why = (f"{pairs} the gyro turns more than {cfg.rotation_check_max_ratio:g}x as far as the "
                   "camera: a gyroscope logging deg/s (DAVIO reads rad/s) or at a wrong full scale?")
        else:
            why = (f"{pairs} the camera turns as far as the gyro but the two rotations differ by more than "
                   f"{np.degrees(cfg.max_visual_gyro_residual_rad):.1f} deg (median "
                   f"{np.degrees(agree.median_rad):.1f} deg): a camera-IMU rotation that is not the rig's "
                   "(T_cam_imu given as T_imu_cam?), or a camera-IMU time offset far from the rig's")
        raise _Rejected("rotation_mismatch", why)


class _Rejected(Exception):
    """A stage of the initializer declined: reason code and message for the RejectionLog."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(f"{code}: {message}")
        self.code = code
        self.message = message
