"""The feed-forward initializer: one 5-image window + IMU -> an InitResult or a Rejection.

Steps (paper Sec. IV): DA3 start-up call; confidence-gated sampling; preintegration to each image
at the current bias; gyro-bias alignment of DA3 and IMU rotations and re-preintegration;
conditioning gates and stratified LMedS; acceptance gates; Huber refinement; state at the last
image in a gravity-aligned frame. Every rejection carries its reason.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from models.depth_model import DepthModel, checked_prediction
from runtime.errors import DataError, EstimatorError
from runtime.events import Frame
from runtime.ffinit.config import FFInitConfig
from runtime.ffinit.extension import EXTENDABLE, ExtensionSeed, TrackSet, extended_observations
from runtime.ffinit.extrinsics_check import check_extrinsic_rotation
from runtime.ffinit.gyro_bias import align_gyro_bias, rotation_residuals
from runtime.ffinit.gyro_scale import check_gyro_scale
from runtime.ffinit.linear import scale_bias_sensitivity
from runtime.ffinit.refine import Refined, refine
from runtime.ffinit.robust import RobustResult, robust_solve
from runtime.ffinit.sampling import observations_from_prediction
from runtime.ffinit.state import scale_relative_std, state_at_last_image
from runtime.ffinit.time_offset_check import fit_time_offset
from runtime.ffinit.window import ImageObservations, InitWindow, Rejection
from runtime.imu import Preintegrator
from runtime.msckf.init_common import InitResult


def build_window(t_cam_ns: Sequence[int], observations: list[ImageObservations], imu_t_ns: np.ndarray,
                 gyro: np.ndarray, accel: np.ndarray, R_IC: np.ndarray, p_IC: np.ndarray,
                 time_offset_s: float = 0.0, bg: np.ndarray | None = None,
                 ba: np.ndarray | None = None) -> InitWindow:
    """Preintegrate from the first image to every image (IMU clock = camera clock + offset)."""
    bg = np.zeros(3) if bg is None else np.asarray(bg, float)
    ba = np.zeros(3) if ba is None else np.asarray(ba, float)
    off = int(round(time_offset_s * 1e9))
    t_imu = np.asarray(t_cam_ns, dtype=np.int64) + off
    pre = Preintegrator(bg, ba)
    n = len(t_imu)
    I3 = np.eye(3)
    R, dp, dv = np.tile(I3, (n, 1, 1)), np.zeros((n, 3)), np.zeros((n, 3))
    J = {k: np.zeros((n, 3, 3)) for k in ("R_bg", "p_bg", "p_ba", "v_bg", "v_ba")}
    for i in range(1, n):
        p = pre.integrate(imu_t_ns, gyro, accel, int(t_imu[0]), int(t_imu[i]))
        R[i], dp[i], dv[i] = p.dR, p.dp, p.dv
        J["R_bg"][i], J["p_bg"][i], J["p_ba"][i] = p.J_R_bg, p.J_p_bg, p.J_p_ba
        J["v_bg"][i], J["v_ba"][i] = p.J_v_bg, p.J_v_ba
    dt = (t_imu - t_imu[0]).astype(np.float64) * 1e-9
    return InitWindow(t_ns=t_imu, images=observations, dt=dt, R_I0Ii=R, dp=dp, dv=dv,
                      J_R_bg=J["R_bg"], J_p_bg=J["p_bg"], J_p_ba=J["p_ba"], J_v_bg=J["v_bg"],
                      J_v_ba=J["v_ba"], R_IC=np.asarray(R_IC, float), p_IC=np.asarray(p_IC, float),
                      bg=bg, ba=ba)


def solve_window(window: InitWindow, cfg: FFInitConfig, rebuild=None) -> InitResult | Rejection:
    """Gyro-bias alignment, robust solve, refinement, the scale gates and the state at the last image.

    rebuild(bg) -> InitWindow re-preintegrates at a new gyro bias (None: keep first order).
    """
    bg0 = np.asarray(window.bg, float).copy()
    dbg = align_gyro_bias(window, huber_rad=np.radians(cfg.rotation_huber_deg))
    dbg_total = dbg.copy()
    if not np.linalg.norm(dbg) <= cfg.max_gyro_bias_change:
        return check_extrinsic_rotation(window, cfg, dbg, bg0) or Rejection("gyro_bias_step",
                         f"DA3-gyro alignment asks for a gyro-bias step of {np.linalg.norm(dbg):.3f} rad/s "
                         f"(> {cfg.max_gyro_bias_change})")
    if rebuild is not None and np.linalg.norm(dbg) > 0:
        window = rebuild(window.bg + dbg)
        dbg = np.zeros(3)
    # DA3-gyro consistency after the bias alignment: large DA3 rotation errors make wrong scales
    rot_rms_deg = float(np.degrees(np.sqrt(np.mean(np.sum(rotation_residuals(window, dbg) ** 2, axis=1)))))
    if not rot_rms_deg <= cfg.max_rotation_residual_deg:
        return check_extrinsic_rotation(window, cfg, dbg, bg0) or Rejection("rotation_inconsistent",
                         f"DA3 and gyro rotations differ by {rot_rms_deg:.3f} deg RMS after the bias "
                         f"alignment (> {cfg.max_rotation_residual_deg})")
    if cfg.point_rotations == "gyro":
        window = with_gyro_rotations(window, dbg)
    robust = robust_solve(window, cfg)
    if isinstance(robust, Rejection):
        return robust
    assert isinstance(robust, RobustResult)
    inliers = [np.zeros(len(o.z), bool) for o in window.images]
    offset = 0
    for i in range(1, window.num_images):
        k = len(window.images[i].z)
        inliers[i] = robust.inliers[offset:offset + k]
        offset += k
    ref = refine(window, robust.solution, inliers, cfg, dbg0=dbg)
    if not (np.isfinite(ref.scale) and ref.scale > 0 and np.all(np.isfinite(ref.v0))):
        return Rejection("refinement_failed", "non-finite refined state")
    if np.linalg.norm(ref.v0) > cfg.max_velocity:
        return Rejection("implausible_velocity", f"refined |v0| = {np.linalg.norm(ref.v0):.2f} m/s")
    gate = scale_gates(window, robust, ref, cfg)
    if isinstance(gate, Rejection):
        return gate
    result = state_at_last_image(window, ref, int(window.t_ns[-1]))
    result.info.update({**gate, "linear_scale": robust.solution.scale,
                        "inlier_fraction": robust.inlier_fraction,
                        "median_residual": robust.median_residual, "gyro_bias_change": dbg_total.tolist(),
                        "rotation_residual_rms_deg": rot_rms_deg})
    return result


def with_gyro_rotations(window: InitWindow, dbg: np.ndarray) -> InitWindow:
    """The window with each image's R_C0Ci replaced by the preintegrated R_CI R_I0Ii Exp(J dbg) R_IC."""
    from dataclasses import replace

    from runtime.geometry import so3_exp

    R_CI = window.R_IC.T
    images = [window.images[0]] + [
        replace(o, R_C0Ci=R_CI @ window.R_I0Ii[i] @ so3_exp(window.J_R_bg[i] @ dbg) @ window.R_IC)
        for i, o in enumerate(window.images) if i > 0]
    return replace(window, images=images)


def scale_gates(window: InitWindow, robust: RobustResult, ref: Refined,
                cfg: FFInitConfig) -> dict | Rejection:
    """Refuse a scale the window cannot determine or no camera sees (added to the paper, issue 15).

    Returns the measured values (for the result's info) or the Rejection.
    """
    sens = scale_bias_sensitivity(robust.system.subset(robust.inliers), robust.solution)
    rel_std = scale_relative_std(ref)
    uncertainty = float(np.hypot(rel_std, cfg.accel_bias_sigma * sens))
    if not uncertainty <= cfg.max_scale_uncertainty:
        return Rejection("scale_unobservable",
                         f"scale uncertainty {uncertainty:.3f} > {cfg.max_scale_uncertainty} (sigma_s/s "
                         f"{rel_std:.3f}, a {cfg.accel_bias_sigma} m/s^2 accelerometer bias moves s by "
                         f"{cfg.accel_bias_sigma * sens:.3f}): too little acceleration in the window")
    depths = np.concatenate([o.depth for o in window.images if len(o.depth)])
    median_depth = float(ref.scale * np.median(depths)) if depths.size else 0.0
    if not cfg.min_median_depth_m <= median_depth <= cfg.max_median_depth_m:
        return Rejection("implausible_depth",
                         f"median metric depth {median_depth:.3g} m outside "
                         f"[{cfg.min_median_depth_m}, {cfg.max_median_depth_m}]")
    return {"scale_bias_sensitivity": sens, "scale_uncertainty": uncertainty, "median_depth_m": median_depth,
            "scale_observed_rel_std": scale_relative_std(ref, observed=True)}


OFFSET_CHECKED = ("gyro_bias_step", "rotation_inconsistent")
"""Rejections after which the window's camera-IMU time offset is fitted (runtime.ffinit.time_offset_check)."""


class FeedForwardInitializer:
    """Runs the DA3 start-up call on a window of frames and solves for the metric state.

    Args:
        model: a DepthModel (ONNX DA3 or the emulated DA3).
        R_IC, p_IC: camera–IMU extrinsics (p_IC = 0 when withheld, Sec. IV-D).
        time_offset_s: t_imu = t_cam + time_offset_s.
        use_rig_intrinsics: normalized coordinates from the model's K_rect (calibrated) instead of
            DA3's predicted intrinsics.
    """

    def __init__(self, model: DepthModel, R_IC: np.ndarray, p_IC: np.ndarray, time_offset_s: float = 0.0,
                 cfg: FFInitConfig | None = None, use_rig_intrinsics: bool = True) -> None:
        self.model = model
        self.R_IC = np.asarray(R_IC, float)
        self.p_IC = np.asarray(p_IC, float)
        self.time_offset_s = float(time_offset_s)
        self.cfg = cfg or FFInitConfig()
        self.use_rig_intrinsics = use_rig_intrinsics

    def solve(self, frames: Sequence[Frame], imu_t_ns: np.ndarray, gyro: np.ndarray, accel: np.ndarray,
              bg: np.ndarray | None = None, ba: np.ndarray | None = None) -> InitResult | Rejection:
        """One attempt on `frames` (spaced about 0.2 s) with the IMU samples covering them."""
        if len(frames) < self.cfg.min_images:
            return Rejection("too_few_images", f"{len(frames)} frames < {self.cfg.min_images}")
        t_cam = [int(f.t_ns) for f in frames]
        if any(b <= a for a, b in zip(t_cam, t_cam[1:], strict=False)):
            raise EstimatorError("window frames must have strictly increasing stamps")
        pred = checked_prediction(self.model.predict(list(frames)), frames)
        K = self.model.K_rect if self.use_rig_intrinsics else None
        obs = observations_from_prediction(pred, self.cfg, K=K, seed=self.cfg.seed)
        result = self._solve(t_cam, obs, imu_t_ns, gyro, accel, bg, ba)
        if isinstance(result, InitResult):
            result.info["da3"] = dict(pred.info)
        elif result.reason in EXTENDABLE and K is not None:
            result.seed = ExtensionSeed(np.array(t_cam, np.int64), obs, pred.depth, pred.conf,
                                        np.asarray(K, float), result.reason)
        return result

    def solve_extended(self, seed: ExtensionSeed, tracks: Sequence[TrackSet], imu_t_ns: np.ndarray,
                       gyro: np.ndarray, accel: np.ndarray, bg: np.ndarray | None = None,
                       ba: np.ndarray | None = None) -> InitResult | Rejection:
        """Re-solve a refused window over a longer span, without a model call
        (runtime.ffinit.extension): tracks holds the front-end's tracks in the window's images, then in
        the newer frames (increasing stamps). A rejection a still longer span could cure keeps the seed."""
        ext = extended_observations(seed, tracks, self.cfg)
        if isinstance(ext, Rejection):
            return ext
        t_cam = [int(t) for t in seed.t_cam_ns] + [t for t, _ in ext]
        obs = list(seed.observations) + [o for _, o in ext]
        result = self._solve(t_cam, obs, imu_t_ns, gyro, accel, bg, ba)
        span_s = (t_cam[-1] - t_cam[0]) * 1e-9
        if isinstance(result, InitResult):
            result.info.update({"extended_from": seed.reason, "extended_frames": len(ext),
                                "span_s": span_s})
        elif result.reason in EXTENDABLE:
            result.seed = seed
        return result

    def _solve(self, t_cam: list[int], obs: list[ImageObservations], imu_t_ns: np.ndarray, gyro: np.ndarray,
               accel: np.ndarray, bg: np.ndarray | None, ba: np.ndarray | None) -> InitResult | Rejection:
        """Preintegrate to every image (again at each new gyro bias) and solve the window."""

        def solve_at(offset_s: float) -> InitResult | Rejection:
            def rebuild(bg_new: np.ndarray) -> InitWindow:
                return build_window(t_cam, obs, imu_t_ns, gyro, accel, self.R_IC, self.p_IC, offset_s,
                                    bg_new, ba)

            try:
                window = rebuild(np.zeros(3) if bg is None else bg)
            except DataError as exc:
                return Rejection("imu_gap", str(exc))
            return solve_window(window, self.cfg, rebuild)

        wrong_scale = check_gyro_scale(t_cam, obs, imu_t_ns, gyro, self.time_offset_s, self.cfg)
        if wrong_scale is not None:
            return wrong_scale
        result = solve_at(self.time_offset_s)
        if not (isinstance(result, Rejection) and result.reason in OFFSET_CHECKED):
            return result
        fit = fit_time_offset(t_cam, obs, self.R_IC, imu_t_ns, gyro, self.time_offset_s, self.cfg)
        if fit is None:
            return result
        detail = fit.describe(self.time_offset_s)
        found = self.time_offset_s + fit.shift_s
        if not self.cfg.correct_time_offset:
            return Rejection("time_offset", detail, time_offset_s=found)
        corrected = solve_at(found)
        if isinstance(corrected, Rejection) and corrected.reason == "imu_gap":   # live: the IMU ends near it
            return Rejection("time_offset", f"{detail}; not solved at that offset: the IMU handed to the "
                                            "window does not cover it there", time_offset_s=found)
        if isinstance(corrected, Rejection) and corrected.reason in EXTENDABLE:   # a longer span may cure it
            corrected.detail = f"at the offset the rotations fit ({detail}): {corrected.detail}"
            corrected.time_offset_s = found
            return corrected
        if isinstance(corrected, Rejection):
            return Rejection("time_offset", f"{detail}; solved at that offset the window is refused too "
                                            f"({corrected.reason}: {corrected.detail})", time_offset_s=found)
        corrected.info.update({"time_offset_s": found, "time_offset_shift_s": fit.shift_s,
                               "time_offset_detail": detail})
        return corrected
