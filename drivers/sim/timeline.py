"""The time line of a simulated recording: its frame stamps, the stamps and positions its scene must leave
free, and the trajectory file it follows (cropped; its gaps noted). Stamps are int64 ns on the IMU clock."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from runtime.errors import ConfigError, DataError
from runtime.geometry.trajectory import PoseTrajectory

FRAME_START_S = 0.025
"""The first frame of a synthetic recording comes this long after the first IMU sample, s."""


def frame_times(t0_ns: int, t_end_ns: int, rate_hz: float, margin_ns: int) -> np.ndarray:
    """True (IMU-clock) stamps of the frames at `rate_hz`: the first FRAME_START_S after t0_ns, the last at
    least margin_ns before t_end_ns; ConfigError when not even one fits."""
    period = 1e9 / rate_hz
    first = t0_ns + int(FRAME_START_S * 1e9)
    n = int(np.floor((t_end_ns - margin_ns - first) / period)) + 1
    if n < 1:
        raise ConfigError("the recording is too short for a single camera frame")
    return first + np.round(np.arange(n) * period).astype(np.int64)


def scene_times(t0_ns: int, t_end_ns: int) -> np.ndarray:
    """int64 stamps from t0_ns to t_end_ns (both included) about every 20 ms. Offsets from t0 are spaced in
    float64, not the stamps: at 1.4e18 ns a float64 is 256 ns coarse, and a rounded end stamp fell outside
    the motion's span (a TUM file whose first stamp rounded up)."""
    n = max(2, int((t_end_ns - t0_ns) / 2e7))
    span = int(t_end_ns) - int(t0_ns)
    return int(t0_ns) + np.minimum(np.round(np.linspace(0.0, span, n)).astype(np.int64), span)


def scene_positions(motion, t0_ns: int, t_end_ns: int, T_IC: np.ndarray) -> np.ndarray:
    """Body and camera positions (world, m) of `motion` (a spline: `pose(t_ns)` -> (R_WI, p_WI)) over
    scene_times: what the scene built around the recording must leave free."""
    t = scene_times(t0_ns, t_end_ns)
    R, p = motion.pose(t)
    return np.concatenate([p, p + R @ T_IC[:3, 3]])


def trajectory_positions(traj: PoseTrajectory, T_IC: np.ndarray) -> np.ndarray:
    """Body and camera positions (world, m) of a whole trajectory, every 20 ms at most (as
    `scene_positions`): what a scene built around the whole trajectory file must leave free."""
    step = max(1, int(round(2e7 / max(np.median(np.diff(traj.t_ns)), 1.0)))) if len(traj) > 1 else 1
    p, R = traj.p[::step], traj.R[::step]
    return np.concatenate([p, p + R @ T_IC[:3, 3]])


GAP_MIN_S = 0.2
"""A step between trajectory poses longer than this and ten median steps is a gap (a tracking dropout)."""


def trajectory_gap_notes(t_ns: np.ndarray) -> list[str]:
    """A note when the poses have gaps (a motion-capture dropout): the spline fitted through them makes up
    the motion there, and the IMU and images follow it."""
    if len(t_ns) < 3:
        return []
    step = np.diff(np.asarray(t_ns, np.int64))
    limit = max(GAP_MIN_S * 1e9, 10.0 * float(np.median(step)))
    gaps = np.flatnonzero(step > limit)
    if not len(gaps):
        return []
    k = int(gaps[np.argmax(step[gaps])])
    return [f"the trajectory has {len(gaps)} gap(s) longer than {limit * 1e-9:.2g} s (the longest "
            f"{step[k] * 1e-9:.2f} s, {(t_ns[k] - t_ns[0]) * 1e-9:.2f} s after its first pose): the spline "
            "through the poses makes up the motion there, and the IMU and the images follow it"]


def crop_trajectory(traj: PoseTrajectory, start_s: float, seconds: float | None,
                    path: Path) -> PoseTrajectory:
    """The poses from start_s (after the first) for `seconds` (None: to the end); DataError naming `path`
    when fewer than 4 are left (a spline needs them)."""
    t0 = int(traj.t_ns[0]) + int(round(start_s * 1e9))
    t1 = int(traj.t_ns[-1]) if seconds is None else t0 + int(round(seconds * 1e9))
    out = traj.subset((traj.t_ns >= t0) & (traj.t_ns <= t1))
    if len(out) < 4:
        raise DataError(f"fewer than 4 poses between {start_s} s and {start_s + (seconds or 0)} s", path)
    return out
