"""Settings of the dynamic initializer (:class:`DynamicInitConfig`), OpenVINS ``init_dyn_*`` defaults."""

from __future__ import annotations

import math
from dataclasses import dataclass

from runtime.config_checks import finite_fields, in_range, non_negative, positive
from runtime.errors import ConfigError

MLE_SOLVERS = ("lm", "scipy-fd")
"""The refinement's solvers (DynamicInitConfig.mle_solver)."""


@dataclass
class DynamicInitConfig:
    """Dynamic initializer settings (defaults: OpenVINS EuRoC ``init_dyn_*`` where it has them)."""

    init_window_time_s: float = 2.0
    """Window of frames and IMU used, s (OpenVINS init_window_time)."""
    min_window_fraction: float = 0.9
    """The keyframes must span at least this fraction of the window (OpenVINS waits for a full window)."""
    num_pose: int = 6
    """Keyframes in the window (OpenVINS init_dyn_num_pose)."""
    min_deg: float = 10.0
    """Minimum integrated gyro rotation over the window, degrees (OpenVINS init_dyn_min_deg)."""
    min_parallax_deg: float = 1.0
    """Minimum median rotation-compensated bearing change of the features, degrees."""
    min_features: int = 8
    """Features needed (OpenVINS: 8 valid features)."""
    max_features: int = 50
    """Features used at most, longest tracks first (OpenVINS init_max_features)."""
    min_feature_observations: int = 3
    """Keyframes a feature must be seen in."""
    gravity_mag: float = 9.81
    """Gravity magnitude g0, m/s^2."""
    estimate_gyro_bias: bool = True
    """Estimate the gyro bias from essential-matrix rotations between keyframes before the linear solve."""
    max_visual_gyro_residual_rad: float = 0.2
    """A keyframe pair whose visual and gyro rotations differ by more is left out of that estimate, rad."""
    max_rotation_mismatch_fraction: float = 0.5
    """Before the solves: when more than this fraction of the keyframe pairs measured (at least
    `min_rotation_check_pairs`; two-view fits of their common tracks, through the rig's R_IC) show a rig
    mistake, the window is refused as `rotation_mismatch`: the gyro turning more than
    `rotation_check_max_ratio` times as far as the camera (a gyroscope in deg/s), or the camera turning as
    far as the gyro with the two rotations more than `max_visual_gyro_residual_rad` apart (a camera-IMU
    rotation that is not the rig's, seen on pairs turning more than about 6 deg; a large unmodelled time
    offset does the same). On such a rig the solves cost 0.3-1.5 s a frame and fail (BENCHMARKS.md "The
    dynamic initializer on a wrong rig"; runtime.msckf.init_dynamic_rotation_check). 1.0 turns the check
    off. Not in OpenVINS."""
    rotation_check_max_ratio: float = 15.0
    """A keyframe pair whose gyro turns more than this many times as far as its camera shows a scale mistake
    (a gyroscope in deg/s: 57x; as `ffinit.max_gyro_rate_ratio` and `bringup.max_gyro_ratio`)."""
    rotation_check_min_gyro_deg: float = 5.0
    """Pairs whose gyro turns less are not judged by that ratio: a 0.1 rad/s gyro bias alone turns 2.3 deg
    between keyframes 0.4 s apart while the camera stands (EuRoC's gyro bias reaches 0.08 rad/s)."""
    min_rotation_check_pairs: int = 3
    """Keyframe pairs with a two-view rotation needed before `rotation_mismatch` is judged."""
    rotation_mismatch_retry_s: float = 0.5
    """After a `rotation_mismatch`, the next attempt waits this long (camera seconds; the window slides)."""
    rotation_check_interval_s: float = 0.5
    """After a check in which no pair showed a mistake, the next check waits this long (camera seconds):
    five two-view fits, about 40 ms, on attempts that passed the parallax check; attempts in between go on
    to the solves unchecked. A check with some pairs showing a mistake is repeated at the next attempt."""
    max_condition: float = 1e10
    """Eigenvalue ratio of the reduced velocity block above which the linear system is degenerate."""
    max_feature_condition: float = 1e8
    """Eigenvalue ratio of a feature's 3x3 normal block above which it has no depth information."""
    mle_max_iterations: int = 20
    """Nonlinear refinement's residual evaluations at most (a rejected step counts; scipy least_squares
    max_nfev); a window whose refinement has not converged by then is refused (mle_not_converged), as OpenVINS
    refuses one whose Ceres solve did not converge (its init_dyn_mle_max_iter 20 counts Ceres iterations,
    up to 21 evaluations: this budget is one evaluation tighter; accepted windows of the simulated
    recordings needed at most 18); 0 disables the refinement, 1 would refuse every window."""
    mle_tolerance: float = 1e-6
    """Relative cost / step tolerance that ends the refinement (scipy ftol and xtol)."""
    mle_solver: str = "lm"
    """The refinement's solver: "lm" (the analytic Jacobian, Levenberg-Marquardt on the normal equations:
    runtime.msckf.normal_lm), or "scipy-fd" (scipy least_squares "trf" with forward differences over the
    Jacobian's sparsity pattern and LSMR steps), the way used until the thirty-first session, kept as the
    reference: an attempt that reaches the refinement is 6-10x slower with it (median, `davio bench
    init-cost`)."""
    sigma_px: float = 1.0
    """Pixel noise of the features, px."""
    sigma_bg_prior: float = 0.01
    """Prior std of the gyro bias around bias_g_prior, rad/s."""
    sigma_ba_prior: float = 0.05
    """Prior std of the accelerometer bias around bias_a_prior, m/s^2. A 2 s window barely separates
    this bias from tilt; 0.05 gave a median 0.67 deg gravity error on real V1_02 IMU windows
    (`davio bench euroc-frontend --dynamic`) where 0.2 gave 1.5 deg."""
    bias_g_prior: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Gyro bias guess, rad/s (OpenVINS init_dyn_bias_g)."""
    bias_a_prior: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Accelerometer bias guess, m/s^2 (OpenVINS init_dyn_bias_a)."""
    max_accel_bias_change: float = 1.0
    """An estimated accelerometer bias farther than this from bias_a_prior rejects the solution, m/s^2."""
    max_reprojection_rms_px: float = 3.0
    """After refinement, a larger RMS reprojection error rejects the solution, px."""
    min_positive_depth_fraction: float = 0.9
    """Fraction of features that must lie in front of the first camera after the linear solve."""
    inflation_theta: float = 10.0
    """Variance inflation of the orientation block (OpenVINS init_dyn_inflation_ori)."""
    inflation_p: float = 1.0
    """Variance inflation of the position block."""
    inflation_v: float = 100.0
    """Variance inflation of the velocity block (OpenVINS init_dyn_inflation_vel)."""
    inflation_bg: float = 10.0
    """Variance inflation of the gyro bias block (OpenVINS init_dyn_inflation_bias_gyro)."""
    inflation_ba: float = 100.0
    """Variance inflation of the accelerometer bias block (OpenVINS init_dyn_inflation_bias_accel)."""

    def __post_init__(self) -> None:
        # an upper-bound gate may be switched off with inf; nothing else may be inf, and nothing NaN
        gates = ("max_condition", "max_feature_condition", "max_accel_bias_change", "max_reprojection_rms_px")
        finite_fields(self, "dynamic_init", allow_inf=gates)
        positive(self, "dynamic_init", "mle_tolerance", "sigma_bg_prior", "sigma_ba_prior", "inflation_theta",
                 "inflation_p", "inflation_v", "inflation_bg", "inflation_ba")
        non_negative(self, "dynamic_init", "min_deg", "min_parallax_deg")
        in_range(self, "dynamic_init", "min_window_fraction", 0.0, 1.0, lo_open=True)
        in_range(self, "dynamic_init", "min_positive_depth_fraction", 0.0, 1.0)
        positive(self, "dynamic_init", *gates, finite=False)
        if any(not math.isfinite(float(b)) for b in (*self.bias_g_prior, *self.bias_a_prior)):
            raise ConfigError(f"dynamic_init.bias_g_prior and bias_a_prior must be finite, got "
                              f"{self.bias_g_prior}, {self.bias_a_prior}")
        if self.num_pose < 3:
            raise ConfigError(f"dynamic init num_pose must be >= 3, got {self.num_pose}")
        if not self.init_window_time_s > 0:
            raise ConfigError(f"dynamic init window must be > 0 s, got {self.init_window_time_s}")
        if self.min_feature_observations < 2:
            raise ConfigError(f"min_feature_observations must be >= 2, got {self.min_feature_observations}")
        if self.min_features < 1 or self.max_features < self.min_features:
            raise ConfigError(
                f"need 1 <= min_features <= max_features, got {self.min_features}, {self.max_features}"
            )
        if not self.gravity_mag > 0:
            raise ConfigError(f"gravity_mag must be > 0, got {self.gravity_mag}")
        if self.mle_solver not in MLE_SOLVERS:
            raise ConfigError(f"dynamic_init.mle_solver must be one of {', '.join(MLE_SOLVERS)}, got "
                              f"{self.mle_solver!r}")
        if not self.sigma_px > 0:
            raise ConfigError(f"sigma_px must be > 0, got {self.sigma_px}")
        if self.mle_max_iterations != 0 and self.mle_max_iterations < 2:
            raise ConfigError("dynamic_init.mle_max_iterations must be 0 (no refinement) or >= 2 (1 "
                              "evaluates only the start, which never converges), got "
                              f"{self.mle_max_iterations}")
        if not 0.0 <= self.max_rotation_mismatch_fraction <= 1.0:
            raise ConfigError("dynamic_init.max_rotation_mismatch_fraction must be in [0, 1], got "
                              f"{self.max_rotation_mismatch_fraction}")
        if not (self.rotation_check_max_ratio > 1.0 and self.rotation_check_min_gyro_deg >= 0.0):
            raise ConfigError("dynamic_init.rotation_check_max_ratio must be > 1 and "
                              "rotation_check_min_gyro_deg >= 0, got "
                              f"{self.rotation_check_max_ratio}, {self.rotation_check_min_gyro_deg}")
        if self.min_rotation_check_pairs < 1:
            raise ConfigError(f"dynamic_init.min_rotation_check_pairs must be >= 1, got "
                              f"{self.min_rotation_check_pairs}")
        for name in ("rotation_mismatch_retry_s", "rotation_check_interval_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ConfigError(f"dynamic_init.{name} must be a finite number >= 0, got {v}")
        if not (math.isfinite(self.max_visual_gyro_residual_rad) and self.max_visual_gyro_residual_rad > 0):
            raise ConfigError("dynamic_init.max_visual_gyro_residual_rad must be a finite number > 0, got "
                              f"{self.max_visual_gyro_residual_rad}")
        if self.max_rotation_mismatch_fraction < 1.0 and self.min_rotation_check_pairs > self.num_pose - 1:
            raise ConfigError(f"dynamic_init.min_rotation_check_pairs must be at most num_pose - 1 = "
                              f"{self.num_pose - 1} (the keyframe pairs), got "
                              f"{self.min_rotation_check_pairs}")

    @property
    def window_ns(self) -> int:
        """init_window_time_s in int64 ns."""
        return int(round(self.init_window_time_s * 1e9))

    @property
    def inflation(self) -> tuple[float, float, float, float, float]:
        """Variance inflation per ERROR_STATE_ORDER block (theta, p, v, bg, ba)."""
        return (
            self.inflation_theta, self.inflation_p, self.inflation_v, self.inflation_bg, self.inflation_ba
        )
