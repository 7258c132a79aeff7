"""Configuration of the MSCKF filter (defaults: OpenVINS's EuRoC monocular configuration)."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

from runtime.config_checks import finite_fields, non_negative, positive
from runtime.errors import ConfigError

SLAM_REPRESENTATIONS = ("anchored_inverse_depth", "global_3d")

#: the IMU noise densities used when neither the configuration nor the rig gives one (EuRoC/Kalibr ADIS16448)
DEFAULT_IMU_NOISE = {
    "gyro_noise_density": 1.6968e-4,   # rad/s/sqrt(Hz)
    "gyro_random_walk": 1.9393e-5,     # rad/s^2/sqrt(Hz)
    "accel_noise_density": 2.0e-3,     # m/s^2/sqrt(Hz)
    "accel_random_walk": 3.0e-3,       # m/s^3/sqrt(Hz)
}


@dataclass(frozen=True)
class MsckfConfig:
    """Every threshold of the filter, as a named field.

    IMU noise densities left None come from the rig's calibration, else DEFAULT_IMU_NOISE; a value set here
    overrides the rig (`with_imu_noise`, which the filter always applies).
    """

    # filter
    use_fej: bool = True  #: first-estimate Jacobians (IMU and clones)
    #: with FEJ, linearise feature Jacobians (and set new landmarks' first estimates) at the point
    #: triangulated from the clones' first estimates instead of the current ones (OpenVINS: current). Off:
    #: each clone's first estimate is its pre-update prediction, so the FEJ poses of a window carry the
    #: corrections applied since, and the point's error from them grows as the window's baseline shrinks
    #: (11 clones span 0.5 s at 20 Hz, 1 s at 10 Hz). On openvins_sim/udel_gore_mono_20hz it pulled the gyro
    #: bias 10 sigma off within 5 s (orientation NEES 20 over the first 8 s): whole run 0.245 m / 1.11 deg,
    #: NEES 4.4 / 6.9 with it, 0.124 m / 0.387 deg, NEES 1.5 / 2.2 without; at 10 Hz 0.090 m / 0.159 deg
    #: with, 0.088 m / 0.142 deg without (BENCHMARKS.md, OpenVINS simulator)
    fej_triangulation: bool = False
    gravity_mag: float = 9.81  #: |g|, m/s^2
    # sliding window and features
    max_clones: int = 11  #: clones kept after marginalisation
    #: s, a clone taken less than this after the previous one is marginalised when the next frame comes (its
    #: frame has updated the filter: MSCKF tracks lost then and the SLAM landmarks used it), so the window of
    #: max_clones clones spans about 1 s at any camera rate from 10 Hz up, every clone kept at 10 Hz, every
    #: second at 20 Hz, every third at 30 Hz (0: every frame keeps its clone, as OpenVINS; 11 clones then
    #: span 0.5 s at 20 Hz, and tracks need twice the speed for the parallax to triangulate). Measured on
    #: openvins_sim/udel_gore_mono_20hz over 8 tie-break seeds: median 0.063 m / 0.184 deg, NEES 0.56 / 1.99
    #: with 0.075 against 0.102 m / 0.363 deg, NEES 1.21 / 2.29 (4 seeds) with 0 (OpenVINS: 0.085 m /
    #: 0.270 deg); 10 Hz unchanged; 7.1 against 7.4 ms per frame (BENCHMARKS.md, OpenVINS simulator)
    min_clone_spacing_s: float = 0.075
    max_slam: int = 50  #: SLAM landmarks in the state
    max_slam_in_update: int = 25  #: SLAM features per batched update
    #: a SLAM landmark leaves the state once more than this many of its observations failed the chi-square
    #: gate (OpenVINS 2.7: 1; UpdaterSLAM.cpp increments update_fail_count on each rejection and
    #: VioManager.cpp marginalises above 1); None: a rejection drops only that observation. On
    #: openvins_sim/udel_gore_mono (24 tie-break seeds) the two are within the seed spread (None: 0.066 m /
    #: 0.175 deg median, 1: 0.073 m / 0.175 deg); at robot rates (udel_gore_mono_20hz, 8 seeds) None is
    #: better: 0.063 m / 0.184 deg against 0.085 m / 0.253 deg (OpenVINS's own run: 0.085 m / 0.270 deg)
    slam_max_chi2_failures: int | None = None
    max_msckf_in_update: int = 40  #: MSCKF features per update (longest tracks first)
    dt_slam_delay: float = 1.0  #: s after initialisation before SLAM features are added
    slam_representation: str = "anchored_inverse_depth"  #: SLAM landmark parameters: or "global_3d"
    #: keep lost/marginal tracks not chosen for this frame's MSCKF update for a later one (as OpenVINS)
    keep_unselected_tracks: bool = True
    #: order in which tracks of equal length compete for the MSCKF update: None keeps the feature
    #: database's order (first appearance); an int shuffles the candidates each frame with a generator
    #: seeded by it (OpenVINS's order is its hash map's; benchmarks vary this). New SLAM landmarks are
    #: always the earliest-created full-window tracks, as in OpenVINS.
    feature_order_seed: int | None = None
    # measurement noise and gating
    sigma_pix: float = 1.0  #: pixel noise of MSCKF and SLAM measurements, px
    chi2_multiplier: float = 1.0  #: multiplier of the 95% chi-square threshold
    # triangulation (OpenVINS FeatureInitializerOptions, with cond(A) and depth/baseline opened from its
    # 1e4 / 40). Turning about the IMU the camera moves only on its lever arm, so OpenVINS's gates refuse
    # every track and the filter drifts (the rotation preset: 0.75 m in 10 s, the start-up benchmark's one
    # wrong publication); at 1e5 / 70 it holds (0.03 m), published_wrong is 0 on every start-up recording at
    # every K, and the measured-IMU room map's margin is met at 5 of 5 seeds. The cost is at the new edge:
    # slow motion in front of a distant scene takes tracks that look nearer than they are (2.3 cm after 6 s
    # at 0.08 m/s with a perfect IMU), the constant-velocity preset's drift grows, and OpenVINS's 10 Hz
    # simulator shows 10 % more mean position error (nothing at 20 Hz, nor with ratios 60, 80 or 100 at
    # 10 Hz). BENCHMARKS "Triangulation gates for turning in place"; `davio bench openvins-sim` runs
    # OpenVINS's own gates
    tri_max_cond: float = 1e5  #: reject when cond(A) of the linear system exceeds this
    tri_min_dist: float = 0.10  #: m, minimum depth in the anchor camera
    tri_max_dist: float = 60.0  #: m, maximum depth in the anchor camera
    tri_max_baseline_ratio: float = 70.0  #: reject when depth / max baseline exceeds this
    tri_gn_iterations: int = 20  #: Gauss-Newton (Levenberg-Marquardt) iterations
    # online calibration
    calib_extrinsics: bool = False  #: estimate R_IC, p_IC
    #: estimate t_imu - t_cam in the state (as OpenVINS 2.7's euroc_mav, tum_vi, kaist and rs_d455 configs,
    #: calib_cam_timeoffset). A rig file's offset 20 ms off made the filter with a fixed offset diverge on
    #: five of six 30 s simulations (3-10 resets), 50 ms off on all six; estimated, no reset but one (MH_03 at
    #: -50 ms), the offset within 1.2 ms at the end, and the right rig's ATE the same within 0.005 m
    #: (BENCHMARKS "The camera-IMU time offset in the filter's state"; `davio bench vio-sim
    #: --time-offset-error ... --calib-time-offset both`)
    calib_time_offset: bool = True
    #: estimate the camera intrinsics [fx, fy, cx, cy, d0..d3] (radtan and rational k1 k2 p1 p2, or
    #: equidistant k1..k4; k3..k6 stay fixed) in the state, as OpenVINS's calib_cam_intrinsics. The
    #: filter's residuals and undistortion use the estimate; the KLT front-end and the native initializers
    #: keep the rig's
    calib_intrinsics: bool = False
    # initial calibration uncertainty when estimated
    sigma_calib_rot: float = 0.035  #: rad, prior std of R_IC (about 2 deg)
    sigma_calib_pos: float = 0.02  #: m, prior std of p_IC
    sigma_calib_dt: float = 0.01  #: s, prior std of the time offset
    #: px, prior std of fx and fy (OpenVINS State constructor: 1.0 px for fx fy cx cy, which is also the
    #: std of its simulator's intrinsics perturbation, Simulator::perturb_parameters)
    sigma_calib_focal: float = 1.0
    sigma_calib_center: float = 1.0  #: px, prior std of cx and cy (OpenVINS: 1.0 px)
    #: prior std of each of the four distortion coefficients (OpenVINS State constructor and simulator
    #: perturbation: 0.005)
    sigma_calib_distortion: float = 0.005
    # IMU noise (continuous-time densities). None: the rig's value, else DEFAULT_IMU_NOISE; a value here
    # overrides the rig's
    gyro_noise_density: float | None = None  #: rad/s/sqrt(Hz)
    gyro_random_walk: float | None = None  #: rad/s^2/sqrt(Hz)
    accel_noise_density: float | None = None  #: m/s^2/sqrt(Hz)
    accel_random_walk: float | None = None  #: m/s^3/sqrt(Hz)
    # zero-velocity update. On by default with OpenVINS's disparity-based decision (its ZUPT configs:
    # chi2 multiplier 0, 0.5 px), although its EuRoC file has try_zupt false: a robot standing still has
    # no parallax, so without it the filter dead-reckons. `bench vio-sim` EuRoC-trajectory V1_02 (2.5 s at
    # rest after the start): ATE 0.147 -> 0.030 m. The IMU residuals get 100x the noise variance (OpenVINS's
    # configs: 10x): 10x pulled MH_03's tilt to absorb the accelerometer bias its start lacks while standing
    # (rotation ATE 1.6 deg against 0.84 with 100x and 0.62 without ZUPT, position 0.041 m in all three)
    try_zupt: bool = True  #: detect standstill and apply a zero-velocity update
    zupt_chi2_multiplier: float = 0.0  #: multiplier of the ZUPT IMU chi-square threshold (0: disparity only)
    zupt_max_velocity: float = 0.1  #: m/s, the IMU test also needs the estimated speed below this
    #: variance multiplier of the IMU noise in the ZUPT residuals (OpenVINS's zupt_noise_multiplier); the
    #: v = 0 row (ours) has std sqrt(multiplier) * accel_noise_density * sqrt(IMU dt)
    zupt_noise_multiplier: float = 100.0
    #: px, features moving less than this on average (over > 20 of them) mean standstill whatever the IMU
    #: test says (OpenVINS's rule; 0: IMU test only)
    zupt_max_disparity: float = 0.5
    #: s, the disparity is measured against observations at least this old (OpenVINS: the previous frame),
    #: so that slow motion is not taken for standstill: 0.5 px over 0.4 s is 3 cm/s at 6 m
    zupt_disparity_span_s: float = 0.4
    # initialisation from a given state: covariance floors (std), OpenVINS initialize_with_gt values
    init_sigma_ori: float = 0.017  #: rad
    init_sigma_pos: float = 0.05  #: m
    init_sigma_vel: float = 0.01  #: m/s
    init_sigma_bg: float = 0.02  #: rad/s
    init_sigma_ba: float = 0.02  #: m/s^2
    # IMU stream handling
    max_imu_gap_s: float = 0.05  #: a larger gap between IMU samples is counted as a gap
    #: s, a longer gap between IMU samples resets a running filter: its state cannot be propagated across it
    #: (after a 1 s gap the published poses drifted 12 m with a 0.05-0.24 m position std for 7 s)
    max_imu_outage_s: float = 0.5
    max_imu_extrapolation_s: float = 0.01  #: a frame may lie this far past the newest IMU sample
    #: s, frames waiting for IMU coverage this much older than the newest frame are dropped, counted (was 20
    #: frames, 1 s at 20 Hz: a time, so that the bound holds at any camera rate)
    max_pending_s: float = 1.0
    imu_buffer_s: float = 10.0           #: IMU history kept while uninitialised (for a state in the past), s
    # compute
    blas_threads: int | None = 1  #: BLAS threads for the process (None: leave as is); see blas_threads.py
    #: load the per-frame numba kernels when the estimator is built (a synthetic window, once per process),
    #: not in the first frames after initialisation; see warmup.py
    warm_kernels: bool = True
    # health
    max_velocity: float = 30.0  #: m/s, a faster estimate is a divergence
    max_gyro_bias: float = 0.5  #: rad/s
    max_accel_bias: float = 2.0  #: m/s^2
    max_position_std: float = 100.0  #: m, a larger position std is a covariance blow-up
    #: s without a feature update before a reset (was 50 frames, 2.5 s at 20 Hz). Every health window below is
    #: a time, not a frame count, so that a check means the same at 10, 20 or 30 Hz (the frame counts were
    #: set at EuRoC's 20 Hz and have been converted at that rate)
    max_time_without_update_s: float = 2.5
    #: share of the chi-square-tested visual measurements (MSCKF features and SLAM landmark observations)
    #: rejected over the last `chi2_health_window_s` seconds of frames with a visual update, above which the
    #: filter contradicts the images and is reset (a wrong-scale or wrong-gravity start drifts this way).
    #: Measured: healthy filters stay below 0.1 (openvins-sim 0.07), start-up windows that recovered
    #: reached 0.36-0.64, the three that drifted 3-8 m 0.84-0.87 (`davio bench startup --da3 base_upper`).
    #: 1.0 disables the check
    max_chi2_rejection_fraction: float = 0.75
    chi2_health_window_s: float = 2.0  #: s of frames with a visual update in that window (was 40 frames)
    min_chi2_health_tests: int = 100  #: tested measurements the window needs before the share is judged
    #: fewest visual measurements (MSCKF features + SLAM observations) the filter must accept over its last
    #: `visual_health_window_s` seconds of frames past the update step; below it the filter only dead-reckons
    #: on the IMU while a rare accepted feature keeps `max_time_without_update_s` from firing, and is
    #: reset. Its tracks then fail triangulation because the state is wrong (a wrong-scale or wrong-velocity
    #: start). Measured over every `davio bench startup` window of the presets and V1_02 / MH_03 with the
    #: check off: healthy published segments accepted >= 32 (nearly all > 300), the segments that drifted
    #: 0.9-15 m accepted 0-1. 0 disables the check.
    min_visual_measurements: int = 10
    #: s of frames past the update step in that window (was 40 frames, 2 s at EuRoC's 20 Hz)
    visual_health_window_s: float = 2.0
    #: deg, frames that accept nothing while the filter moves (speed >= zupt_max_velocity, and the
    #: zero-velocity disparity test does not say standstill) but whose MSCKF/SLAM candidate tracks have a
    #: median parallax (rotation removed, first to last observation) below this are not counted against the
    #: filter and restart the count: OpenVINS's depth/baseline gate of 40 cannot triangulate them (it needs
    #: atan(1/40) = 1.43 deg), so they say little about the state. Kept at 1.43 with our gate of 70 (0.82
    #: deg), with which every measurement ran: the band 0.82-1.43 deg is excused although our gate could
    #: triangulate it (deliberately lenient; 0.82 not measured). Slow or
    #: distant motion at a high frame rate is such a case: 11 clones span 0.5 s at 20 Hz, and 0.2 m/s across
    #: a scene 6 m away gives 0.95 deg (10 Hz: 1.9 deg); the filter was reset after 44 frames at 20 Hz and
    #: ran through at 10 Hz. Measured on openvins_sim/udel_gore: 1 % of frames have an MSCKF-candidate median
    #: below 1.6 deg at 20 Hz (2.5 deg at 10 Hz); the 5 frames of 1196 below 1.43 deg triangulated 7 of
    #: their 50 tracks. 0 disables
    visual_health_min_parallax_deg: float = 1.43
    #: s after a zero-velocity update before the restarted count is first judged: motion out of a
    #: standstill needs time to build parallax (a healthy MH_03 start at 20 Hz that stood still, then moved
    #: slowly, accepted 0 measurements over its first 40 frames (2 s) and 415 over its first 60 (3 s))
    visual_health_after_zupt_s: float = 3.0

    def __post_init__(self) -> None:
        finite_fields(self, "msckf")
        positive(self, "msckf", "tri_min_dist", "tri_max_dist", "tri_max_cond", "tri_max_baseline_ratio",
                 "init_sigma_ori", "init_sigma_pos", "init_sigma_vel", "init_sigma_bg", "init_sigma_ba",
                 "max_imu_gap_s", "max_imu_outage_s", "imu_buffer_s", "max_velocity", "max_gyro_bias",
                 "max_accel_bias", "max_position_std", "sigma_calib_rot", "sigma_calib_pos", "sigma_calib_dt")
        non_negative(self, "msckf", "dt_slam_delay", "max_imu_extrapolation_s")
        if self.max_imu_outage_s < self.max_imu_gap_s:
            raise ConfigError(f"msckf.max_imu_outage_s ({self.max_imu_outage_s:g} s) must be at least "
                              f"msckf.max_imu_gap_s ({self.max_imu_gap_s:g} s): a gap is counted before it "
                              "resets")
        if self.slam_representation not in SLAM_REPRESENTATIONS:
            raise ConfigError(
                f"slam_representation must be one of {SLAM_REPRESENTATIONS}, got {self.slam_representation!r}"
            )
        if self.max_clones < 2:
            raise ConfigError(f"max_clones must be >= 2, got {self.max_clones}")
        if self.slam_max_chi2_failures is not None and self.slam_max_chi2_failures < 0:
            raise ConfigError("slam_max_chi2_failures must be >= 0 or unset, "
                              f"got {self.slam_max_chi2_failures}")
        for f in ("max_slam", "max_slam_in_update", "max_msckf_in_update"):
            if getattr(self, f) < 0:
                raise ConfigError(f"{f} must be >= 0, got {getattr(self, f)}")
        for f in (
            "sigma_pix",
            "chi2_multiplier",
            "gravity_mag",
        ):
            if not getattr(self, f) > 0:
                raise ConfigError(f"{f} must be > 0, got {getattr(self, f)}")
        for f in DEFAULT_IMU_NOISE:
            v = getattr(self, f)
            if v is not None and not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ConfigError(f"{f} must be finite and > 0 (or unset: the rig's value), got {v!r}")
        if not (math.isfinite(self.zupt_noise_multiplier) and self.zupt_noise_multiplier > 0):
            raise ConfigError("zupt_noise_multiplier must be finite and > 0, "
                              f"got {self.zupt_noise_multiplier!r}")
        for f in ("zupt_chi2_multiplier", "zupt_max_velocity", "zupt_max_disparity", "zupt_disparity_span_s"):
            v = getattr(self, f)
            if not (math.isfinite(v) and v >= 0):
                raise ConfigError(f"{f} must be finite and >= 0, got {v!r}")
        if not 0.0 < self.max_chi2_rejection_fraction <= 1.0:
            raise ConfigError("max_chi2_rejection_fraction must be in (0, 1], "
                              f"got {self.max_chi2_rejection_fraction}")
        sp = self.min_clone_spacing_s
        if not (isinstance(sp, int | float) and math.isfinite(sp) and sp >= 0):
            raise ConfigError(f"min_clone_spacing_s must be finite and >= 0, got {sp!r}")
        for f in ("max_pending_s", "max_time_without_update_s", "chi2_health_window_s",
                  "visual_health_window_s", "visual_health_after_zupt_s"):
            v = getattr(self, f)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ConfigError(f"{f} must be a finite number of seconds > 0, got {v!r}")
        if self.min_chi2_health_tests < 1:
            raise ConfigError("min_chi2_health_tests must be >= 1")
        v = self.visual_health_min_parallax_deg
        if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
            raise ConfigError("visual_health_min_parallax_deg must be finite and >= 0, "
                              f"got {v!r}")
        if self.min_visual_measurements < 0:
            raise ConfigError(f"min_visual_measurements must be >= 0, got {self.min_visual_measurements}")
        if self.visual_health_after_zupt_s < self.visual_health_window_s:
            raise ConfigError(f"visual_health_after_zupt_s ({self.visual_health_after_zupt_s}) "
                              f"must be >= visual_health_window_s ({self.visual_health_window_s})")
        if self.calib_intrinsics:
            for f in ("sigma_calib_focal", "sigma_calib_center", "sigma_calib_distortion"):
                v = getattr(self, f)
                if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                    raise ConfigError(f"{f} (prior std of the online intrinsics) must be finite and > 0, "
                                      f"got {v!r}")

    def defaulted_imu_noise(self, imu: object | None) -> list[str]:
        """The IMU noise densities `with_imu_noise` takes from DEFAULT_IMU_NOISE: set neither here nor by
        the ImuNoise-like `imu` (withheld calibration), so a run can say so."""
        return [n for n in DEFAULT_IMU_NOISE
                if getattr(self, n) is None and (imu is None or getattr(imu, n, None) is None)]

    def with_imu_noise(self, imu: object | None) -> MsckfConfig:
        """A copy with every IMU noise density resolved: the value set in this configuration, else the
        ImuNoise-like `imu`'s (None, or a field None: withheld), else DEFAULT_IMU_NOISE."""
        vals = {}
        for n, default in DEFAULT_IMU_NOISE.items():
            own = getattr(self, n)
            if own is not None:
                vals[n] = float(own)
                continue
            v = getattr(imu, n, None) if imu is not None else None
            if v is None:
                vals[n] = default
                continue
            v = float(v)
            if not (math.isfinite(v) and v > 0):   # never a default for a value the calibration gave
                raise ConfigError("IMU noise must be finite and positive (null: withheld, the defaults "
                                  f"apply); got {n} = {v!r}")
            vals[n] = v
        return replace(self, **vals)

    def updated(self, **kwargs: object) -> MsckfConfig:
        """A copy with fields replaced; unknown names raise ConfigError."""
        names = {f.name for f in fields(self)}
        bad = sorted(set(kwargs) - names)
        if bad:
            raise ConfigError(f"unknown MsckfConfig fields: {', '.join(bad)}")
        return replace(self, **kwargs)
