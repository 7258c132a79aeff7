"""Timestamp association of two trajectories (nearest stamp within a maximum difference).

Matches evo's `sync.associate_trajectories` (nearest_time): the trajectory with fewer poses (the
estimate when both have as many) is walked in order and each of its stamps takes the nearest stamp of
the other one when the difference is at most `max_diff`; at an exact tie the earlier stamp wins. As in
evo, a pose of the longer trajectory may serve two stamps (e.g. a repeated estimate stamp); with
`one_to_one=True` it serves only the closest one (the first on ties).
"""
from __future__ import annotations

import numpy as np

from runtime.errors import TrajectoryError
from runtime.geometry.trajectory import PoseTrajectory


def match_stamps(short_ns: np.ndarray, long_ns: np.ndarray, max_diff_ns: int,
                 one_to_one: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i_short, i_long) of nearest stamps within `max_diff_ns`.

    Args:
        short_ns, long_ns: int64 stamps, each non-decreasing.
        max_diff_ns: largest accepted |difference|, ns.
        one_to_one: use each long index at most once (the closest short stamp keeps it).
    """
    short_ns = np.asarray(short_ns, dtype=np.int64)
    long_ns = np.asarray(long_ns, dtype=np.int64)
    if long_ns.size == 0 or short_ns.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    if np.any(np.diff(long_ns) < 0) or np.any(np.diff(short_ns) < 0):
        raise TrajectoryError("stamps must not decrease for association")
    upper = np.clip(np.searchsorted(long_ns, short_ns, side="right"), 0, long_ns.size - 1)
    lower = np.clip(upper - 1, 0, long_ns.size - 1)
    d_up = np.abs(long_ns[upper] - short_ns)
    d_lo = np.abs(short_ns - long_ns[lower])
    take_lower = d_lo <= d_up
    best = np.where(take_lower, lower, upper)
    diff = np.where(take_lower, d_lo, d_up)
    ok = diff <= max_diff_ns
    i_short = np.flatnonzero(ok)
    i_long = best[ok]
    diff = diff[ok]
    if not one_to_one:
        return i_short, i_long
    # one-to-one: for a long index chosen more than once, keep the smallest difference (first on ties)
    order = np.lexsort((i_short, diff, i_long))
    first = np.ones(order.size, dtype=bool)
    first[1:] = i_long[order][1:] != i_long[order][:-1]
    keep = np.sort(order[first])
    return i_short[keep], i_long[keep]


def associate(est: PoseTrajectory, ref: PoseTrajectory, max_diff_s: float = 0.01,
              offset_s: float = 0.0, one_to_one: bool = False) -> tuple[PoseTrajectory, PoseTrajectory]:
    """Pairs of poses of `est` and `ref` at (nearly) equal stamps.

    Args:
        est, ref: trajectories with strictly increasing stamps.
        max_diff_s: largest accepted stamp difference, seconds (evo_ape's default 0.01 s).
        offset_s: added to the stamps of `est` before matching (`est` keeps its own stamps).
        one_to_one: never pair one pose with two stamps (evo does; the default follows evo).

    Returns:
        (est_matched, ref_matched) of equal length, in time order.

    Raises:
        TrajectoryError: no pair is within `max_diff_s`.
    """
    max_diff_ns = int(round(max_diff_s * 1e9))
    t_est = est.t_ns + int(round(offset_s * 1e9))
    if len(ref) >= len(est):      # as evo: the estimate is walked unless the reference has fewer poses
        i_est, i_ref = match_stamps(t_est, ref.t_ns, max_diff_ns, one_to_one)
    else:
        i_ref, i_est = match_stamps(ref.t_ns, t_est, max_diff_ns, one_to_one)
    if i_est.size == 0:
        raise TrajectoryError(
            f"no matching stamps within {max_diff_s} s: estimate spans "
            f"{_span(est)}, reference spans {_span(ref)} (offset {offset_s} s)")
    return est.subset(i_est), ref.subset(i_ref)


def _span(traj: PoseTrajectory) -> str:
    if len(traj) == 0:
        return "no poses"
    return f"{traj.t_ns[0] * 1e-9:.3f}..{traj.t_ns[-1] * 1e-9:.3f} s ({len(traj)} poses)"
