"""Keyframes and features of the dynamic initializer, taken from the buffered track history.

A frame is the tuple :class:`runtime.msckf.init_common.TrackWindow` stores: ``(t_ns, ids, uv, xy)``
with the camera-clock time (int64 ns), track ids (M,), distorted pixels (M, 2) and normalized
undistorted image coordinates xy = (x/z, y/z) in the camera frame C (M, 2).

Observations are handed on as rows ``(keyframe index k, feature index n, x, y)`` of a float (N, 4)
array; feature index n points into the chosen id array.
"""

from __future__ import annotations

import numpy as np

Frame = tuple[int, np.ndarray, np.ndarray, np.ndarray]
"""(t_ns camera clock, ids (M,), uv (M, 2) px, xy (M, 2) normalized camera coordinates)."""


def frames_in_window(
    frames: list[Frame], t_imu_newest_ns: int | None, time_offset_ns: int, window_ns: int
) -> list[Frame]:
    """The frames of the window ending at the newest frame the IMU has reached.

    A frame at camera time t is covered once ``t + time_offset_ns <= t_imu_newest_ns`` (IMU clock,
    ns); when none is, the oldest frame is kept alone. Of those, the frames at most ``window_ns``
    before the newest one are returned (oldest first). ``frames`` must not be empty.
    """
    if t_imu_newest_ns is not None:
        frames = [f for f in frames if f[0] + time_offset_ns <= t_imu_newest_ns] or frames[:1]
    t_newest = frames[-1][0]
    return [f for f in frames if f[0] >= t_newest - window_ns]


def pick_keyframes(frames: list[Frame], num_pose: int) -> list[Frame]:
    """Up to ``num_pose`` frames spread evenly (by index) from the first to the last one."""
    pick = np.unique(np.round(np.linspace(0, len(frames) - 1, num_pose)).astype(int))
    return [frames[i] for i in pick]


def select_features(
    keyframes: list[Frame], min_observations: int, max_features: int
) -> tuple[np.ndarray, np.ndarray]:
    """Feature ids seen in >= ``min_observations`` keyframes and their observations.

    The ``max_features`` most observed ids are kept (ties: smaller id first). Returns the chosen
    ids (F,) int64 and the observation rows (k, n, x, y) (N, 4) in keyframe order; observations
    with non-finite normalized coordinates are left out.
    """
    counts: dict[int, int] = {}
    for _, ids, _, _ in keyframes:
        for i in ids.tolist():
            counts[i] = counts.get(i, 0) + 1
    eligible = sorted((-c, i) for i, c in counts.items() if c >= min_observations)
    chosen = np.array([i for _, i in eligible[:max_features]], dtype=np.int64)
    index = {int(i): n for n, i in enumerate(chosen)}
    rows = []
    for k, (_, ids, _, xy) in enumerate(keyframes):
        for j, i in enumerate(ids.tolist()):
            n = index.get(i)
            if n is not None and np.all(np.isfinite(xy[j])):
                rows.append((k, n, xy[j, 0], xy[j, 1]))
    obs = np.array(rows, dtype=np.float64).reshape(-1, 4)
    return chosen, obs


def keep_features(obs: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Observation rows (k, n, x, y) of the features with ``keep[n]`` True, renumbered 0..kept-1."""
    new_index = np.cumsum(keep) - 1
    out = obs[keep[obs[:, 1].astype(int)]].copy()
    out[:, 1] = new_index[out[:, 1].astype(int)]
    return out
