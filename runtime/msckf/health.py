"""Divergence detection: non-finite state, covariance blow-up, velocity/bias bounds, starvation, and
sustained chi-square rejection of the visual measurements; the tracks' parallax that tells a blind filter
from one whose scene lacks parallax."""
from __future__ import annotations

import numpy as np

from runtime.msckf.camera_kernels import CameraParams
from runtime.msckf.config import MsckfConfig
from runtime.msckf.state import State
from runtime.msckf.track_linearization import WindowArrays, pack_tracks


def divergence_reason(state: State, cfg: MsckfConfig, seconds_without_update: float,
                      chi2_tested: int = 0, chi2_rejected: int = 0,
                      visual_accepted: int | None = None) -> str | None:
    """A short reason when the filter has diverged, else None.

    seconds_without_update: camera time since the last frame with a feature update.
    chi2_tested / chi2_rejected: visual measurements that reached the chi-square gate over the last
    `cfg.chi2_health_window_s` seconds, and how many of them it rejected.
    visual_accepted: visual measurements accepted over the last `cfg.visual_health_window_s` seconds of frames
    past the update step, or None until the count may be judged (after an initialization, a reset or a
    zero-velocity update: see `MsckfConfig.visual_health_after_zupt_s`).
    """
    vals = (state.R, state.p, state.v, state.bg, state.ba)
    if not all(np.all(np.isfinite(x)) for x in vals) or not np.all(np.isfinite(state.P)):
        return "non-finite state or covariance"
    d = np.diag(state.P)
    if np.any(d < -1e-9):
        return "negative covariance diagonal"
    if np.sqrt(max(d[3:6].max(), 0.0)) > cfg.max_position_std:
        return f"position std {np.sqrt(d[3:6].max()):.3g} m > {cfg.max_position_std} m"
    speed = float(np.linalg.norm(state.v))
    if speed > cfg.max_velocity:
        return f"speed {speed:.3g} m/s > {cfg.max_velocity} m/s"
    if float(np.abs(state.bg).max()) > cfg.max_gyro_bias:
        return f"gyro bias {np.abs(state.bg).max():.3g} rad/s > {cfg.max_gyro_bias}"
    if float(np.abs(state.ba).max()) > cfg.max_accel_bias:
        return f"accel bias {np.abs(state.ba).max():.3g} m/s^2 > {cfg.max_accel_bias}"
    if seconds_without_update > cfg.max_time_without_update_s:
        return f"no feature update for {seconds_without_update:.2f} s"
    if visual_accepted is not None and visual_accepted < cfg.min_visual_measurements:
        return (f"only {visual_accepted} visual measurements accepted over {cfg.visual_health_window_s:g} s "
                f"(< {cfg.min_visual_measurements}): dead reckoning on the IMU")
    if (cfg.max_chi2_rejection_fraction < 1.0 and chi2_tested >= cfg.min_chi2_health_tests
            and chi2_rejected > cfg.max_chi2_rejection_fraction * chi2_tested):
        return (f"chi-square rejected {chi2_rejected} of {chi2_tested} visual measurements over "
                f"{cfg.chi2_health_window_s:g} s (> {cfg.max_chi2_rejection_fraction:.0%})")
    return None


def median_parallax_deg(state: State, tracks: list, cam: CameraParams) -> float | None:
    """Median over `tracks` of the angle (deg) between the rays of each track's first and last observation at
    the state's clones, both rotated into the odometry frame (the rotation of the camera is removed, so the
    angle is parallax from translation; it needs only the clones' rotations, which the gyro keeps right even
    when the translation is wrong). None without a track observed at two clones."""
    if not tracks or not state.clones:
        return None
    win = WindowArrays(state)
    ptr, slots, _, xn = pack_tracks(state, win, tracks, cam)
    first, last = ptr[:-1], ptr[1:] - 1
    two = last > first
    if not np.any(two):
        return None

    def rays(k: np.ndarray) -> np.ndarray:
        f = np.c_[xn[k], np.ones(k.size)] @ state.R_IC.T
        b = np.einsum("nij,nj->ni", win.R[slots[k]], f)
        return b / np.linalg.norm(b, axis=1, keepdims=True)

    cos = np.einsum("ni,ni->n", rays(first[two]), rays(last[two]))
    return float(np.degrees(np.median(np.arccos(np.clip(cos, -1.0, 1.0)))))
