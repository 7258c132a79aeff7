"""Validation and slicing of IMU sample arrays (int64 ns stamps, rad/s, m/s^2)."""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from runtime.errors import DataError
from runtime.events import ImuSample

ImuArrays = tuple[np.ndarray, np.ndarray, np.ndarray]


def as_imu_arrays(samples: Sequence[ImuSample] | ImuArrays) -> ImuArrays:
    """(t_ns (M,) int64, gyro (M, 3), accel (M, 3)) from ImuSample objects or a tuple of arrays."""
    if isinstance(samples, tuple) and len(samples) == 3 and not hasattr(samples[0], "t_ns"):
        t_ns, gyro, accel = samples
    else:
        t_ns = np.array([s.t_ns for s in samples], dtype=np.int64)
        gyro = np.array([s.gyro for s in samples], dtype=np.float64).reshape(-1, 3)
        accel = np.array([s.accel for s in samples], dtype=np.float64).reshape(-1, 3)
    return check_imu_arrays(t_ns, gyro, accel)


def check_imu_arrays(t_ns: object, gyro: object, accel: object, first_index: int = 0) -> ImuArrays:
    """The arrays as int64 / float64 after checking shapes, finiteness and strictly increasing stamps.

    Raises DataError naming the first offending sample (numbered from `first_index`).
    """
    t = np.asarray(t_ns)
    if t.ndim != 1 or (t.size and not np.issubdtype(t.dtype, np.integer)):
        raise DataError(f"IMU stamps must be a 1-D integer (ns) array, got dtype {t.dtype} shape {t.shape}")
    t = t.astype(np.int64)
    g = np.asarray(gyro, dtype=np.float64)
    a = np.asarray(accel, dtype=np.float64)
    for name, arr in (("gyro", g), ("accel", a)):
        if arr.shape != (t.size, 3):
            raise DataError(f"IMU {name} must have shape ({t.size}, 3), got {arr.shape}")
        bad = ~np.isfinite(arr).all(axis=1)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise DataError(f"IMU {name} sample {k + first_index} (t = {int(t[k])} ns) is not finite")
    if t.size > 1:
        step = np.diff(t)
        if np.any(step <= 0):
            k = int(np.flatnonzero(step <= 0)[0]) + 1
            raise DataError(f"IMU stamps are not strictly increasing at sample {k + first_index} "
                            f"(t = {int(t[k])} ns)")
    return t, g, a


def imu_segment(t_ns: np.ndarray, gyro: np.ndarray, accel: np.ndarray, t0_ns: int,
                t1_ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The samples covering [t0, t1], with the two ends linearly interpolated onto t0 and t1.

    Returns (dts (K,) s, gyro (K+1, 3), accel (K+1, 3)): node 0 at t0, node K at t1, the samples
    strictly inside in between, and dts the K interval lengths. K = 0 when t0 == t1.
    Raises DataError when [t0, t1] is not covered by the stamps or t1 < t0.
    """
    dts, g, a, _ = imu_nodes(t_ns, gyro, accel, t0_ns, np.array([t1_ns], dtype=np.int64))
    return dts, g, a


def imu_nodes(t_ns: np.ndarray, gyro: np.ndarray, accel: np.ndarray, t0_ns: int,
              t_ends_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Integration nodes from t0 to max(t_ends): the samples inside plus interpolated t0 and ends.

    Returns (dts (K,) s, gyro (K+1, 3), accel (K+1, 3), end_nodes (E,) int64): node 0 is at t0 and
    node end_nodes[e] at t_ends[e]; measurements at t0 and at each end stamp are linearly
    interpolated between the bracketing samples. Raises DataError when an end precedes t0 or
    [t0, max(t_ends)] is not covered by the stamps.
    """
    t_all, g_all, a_all = np.asarray(t_ns), np.asarray(gyro), np.asarray(accel)
    ends = np.asarray(t_ends_ns).reshape(-1)
    if ends.size == 0 or not np.issubdtype(ends.dtype, np.integer):
        raise DataError(f"end stamps must be a non-empty integer (ns) array, got {ends!r}")
    ends = ends.astype(np.int64)
    t0, t1 = int(t0_ns), int(ends.max())
    if int(ends.min()) < t0:
        raise DataError(f"preintegration interval ends before it starts: t0 = {t0} ns, "
                        f"t1 = {int(ends.min())} ns")
    lo = 0
    if (t_all.ndim == 1 and t_all.size > 2 and np.issubdtype(t_all.dtype, np.integer)
            and g_all.shape[:1] == t_all.shape and a_all.shape[:1] == t_all.shape):
        # validate only the samples that bracket [t0, t1]: long recordings are sliced many times
        lo = max(int(np.searchsorted(t_all, t0, side="right")) - 1, 0)
        hi = min(int(np.searchsorted(t_all, t1, side="left")) + 1, t_all.size)
        t_all, g_all, a_all = t_all[lo:hi], g_all[lo:hi], a_all[lo:hi]
    t, g, a = check_imu_arrays(t_all, g_all, a_all, first_index=lo)
    if t.size == 0 or t0 < t[0] or t1 > t[-1]:
        span = "no samples" if t.size == 0 else f"samples span [{int(t[0])}, {int(t[-1])}] ns"
        raise DataError(f"IMU samples do not cover the interval [{t0}, {t1}] ns ({span})")
    # node stamps (ns): t0, the distinct end stamps and the samples strictly inside, sorted
    extra = np.unique(np.concatenate([[t0], ends]))
    inside = (t > t0) & (t < t1) & ~np.isin(t, extra)
    node_t = np.concatenate([extra, t[inside]])
    from_sample = np.concatenate([np.zeros(extra.size, dtype=bool), np.ones(int(inside.sum()), dtype=bool)])
    order = np.argsort(node_t, kind="stable")
    node_t, from_sample = node_t[order], from_sample[order]
    rel = (t - t0).astype(np.float64) * 1e-9
    node_rel = (node_t - t0).astype(np.float64) * 1e-9
    g_nodes = np.stack([np.interp(node_rel, rel, g[:, k]) for k in range(3)], axis=1)
    a_nodes = np.stack([np.interp(node_rel, rel, a[:, k]) for k in range(3)], axis=1)
    g_nodes[from_sample] = g[inside]  # t is increasing, so the inside samples keep their order
    a_nodes[from_sample] = a[inside]
    end_nodes = np.searchsorted(node_t, ends).astype(np.int64)
    return np.diff(node_t).astype(np.float64) * 1e-9, g_nodes, a_nodes, end_nodes
