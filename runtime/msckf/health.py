"""Divergence detection: non-finite state, covariance blow-up, velocity/bias bounds, starvation, and
sustained chi-square rejection of the visual measurements, over the camera-time windows `HealthWindows`
keeps; the tracks' parallax that tells a blind filter from one whose scene lacks parallax."""
from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np

from runtime.msckf.camera_kernels import CameraParams
from runtime.msckf.config import MsckfConfig
from runtime.msckf.state import State
from runtime.msckf.track_linearization import WindowArrays, pack_tracks

WINDOW_SLACK_NS = 1_000_000
"""Health windows (seconds of camera time) are compared with 1 ms of slack, so that frame-time rounding and
jitter neither add nor drop a frame at a window's edge."""


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


class HealthWindows:
    """The camera-time windows `divergence_reason` judges (camera clock, ns; windows in seconds mean the
    same at any frame rate, compared with `WINDOW_SLACK_NS` of slack):

    - the time since the last frame with a feature update (starvation);
    - the chi-square gate's tests and rejections over `chi2_health_window_s` (sustained rejection);
    - the visual measurements accepted over `visual_health_window_s` of frames past the update step (a blind
      filter), judged only `needed_s` after the count (re)started: at an initialisation or a reset, after a
      zero-velocity update (`visual_health_after_zupt_s`), and after a frame whose tracks lack parallax."""

    def __init__(self, cfg: MsckfConfig) -> None:
        self.cfg = cfg
        self.last_update_ns: int | None = None   # camera time of the last frame with a feature update
        self.chi2: deque = deque()     # (t_cam, tested, rejected) per frame with a visual update step
        self.accepted: deque = deque()  # (t_cam, accepted) per frame past the update step since the restart
        self.accepted_since: int | None = None   # camera time the count restarted from (None: the next frame)
        self.needed_s = cfg.visual_health_window_s   # s before the count's first judgement

    def clear(self) -> None:
        """Start over (an initialisation or a reset)."""
        self.last_update_ns = None
        self.chi2.clear()
        self.restart(self.cfg.visual_health_window_s)

    def restart(self, needed_s: float, t_cam: int | None = None) -> None:
        """Restart the blind-filter count from camera time t_cam (None: the next frame past the update step);
        the first judgement comes `needed_s` seconds later (>= the window)."""
        self.accepted.clear()
        self.accepted_since = t_cam
        self.needed_s = needed_s

    def waiting_for_clones(self, t_cam: int) -> None:
        """A frame before the window holds enough clones to triangulate: the blind count starts here (unless
        it already runs)."""
        if not self.accepted:
            self.accepted_since = t_cam

    def add_update(self, t_cam: int, used: int, rejected: int, low_parallax: bool) -> None:
        """A frame past the update step: `used` visual measurements accepted and `rejected` by the chi-square
        gate. A frame whose tracks lack parallax restarts the blind count instead of adding to it."""
        self.chi2.append((t_cam, used + rejected, rejected))
        if low_parallax:
            self.restart(self.cfg.visual_health_window_s, t_cam)
            return
        if self.accepted_since is None:
            self.accepted_since = t_cam
        self.accepted.append((t_cam, used))

    def judge(self, state: State, t_cam: int, updated: bool, counters: Any) -> str | None:
        """After a frame (`updated`: it moved the filter, or said nothing about it): slide the windows to
        t_cam, record the worst figures in `counters` (FilterCounters) and return `divergence_reason`'s."""
        cfg = self.cfg
        if updated or self.last_update_ns is None:
            self.last_update_ns = t_cam
        since_update = (t_cam - self.last_update_ns) * 1e-9
        for win, span in ((self.chi2, cfg.chi2_health_window_s), (self.accepted, cfg.visual_health_window_s)):
            start = t_cam - int(round(span * 1e9)) + WINDOW_SLACK_NS
            while win and win[0][0] <= start:
                win.popleft()
        tested = sum(n for _, n, _ in self.chi2)
        rejected = sum(r for _, _, r in self.chi2)
        if tested >= cfg.min_chi2_health_tests:
            counters.chi2_rejection_fraction_max = max(counters.chi2_rejection_fraction_max,
                                                       rejected / tested)
        accepted = None
        needed_ns = int(round(self.needed_s * 1e9)) - WINDOW_SLACK_NS
        if self.accepted_since is not None and t_cam - self.accepted_since >= needed_ns:
            accepted = sum(n for _, n in self.accepted)
        if accepted is not None:
            counters.visual_accepted_min = (accepted if counters.visual_accepted_min is None
                                            else min(counters.visual_accepted_min, accepted))
        return divergence_reason(state, cfg, since_update - WINDOW_SLACK_NS * 1e-9, tested, rejected,
                                 accepted)
