"""How much the dynamic initializer's window excites the problem: gyro rotation and feature parallax."""

from __future__ import annotations

import numpy as np


def gyro_rotation_deg(
    t_ns: np.ndarray, gyro: np.ndarray, t0_ns: int, t1_ns: int, bg: np.ndarray
) -> float:
    """Integrated rotation angle of the bias-corrected gyro over [t0_ns, t1_ns], degrees.

    Args:
        t_ns: (N,) int64 IMU sample times, ns (IMU clock).  gyro: (N, 3) angular rate in I, rad/s.
        t0_ns, t1_ns: the interval (IMU clock), ns.  bg: (3,) gyro bias, rad/s.

    Sums |mean of neighbouring samples - bg| * dt over the samples inside the interval (trapezoid
    on the rate magnitude; no credit for the parts before the first or after the last sample).
    """
    inside = (t_ns >= t0_ns) & (t_ns <= t1_ns)
    w_in = gyro[inside]
    if w_in.shape[0] < 2:
        return 0.0
    dts = np.diff(t_ns[inside]) * 1e-9
    mid = 0.5 * (w_in[1:] + w_in[:-1]) - bg
    return float(np.degrees(np.sum(np.linalg.norm(mid, axis=1) * dts)))


def median_parallax_deg(obs: np.ndarray, R_0k: np.ndarray, R_IC: np.ndarray) -> float:
    """Median over features of the rotation-compensated angle between first and last bearings, degrees.

    Args:
        obs: (N, 4) observation rows (keyframe k, feature n, x, y), x, y normalized camera coordinates.
        R_0k: (K, 3, 3) keyframe IMU orientations in the first keyframe's IMU frame I0 (R_{I0 Ik}).
        R_IC: (3, 3) camera-to-IMU rotation.

    The first view's bearing is rotated into the last view's camera frame before the angle is taken,
    so pure rotation gives 0; 0.0 when there are no features.
    """
    R_CI = R_IC.T
    angles = []
    for n in np.unique(obs[:, 1]):
        rows = obs[obs[:, 1] == n]
        ka, kb = int(rows[0, 0]), int(rows[-1, 0])
        bearing_a = np.array([rows[0, 2], rows[0, 3], 1.0])
        bearing_b = np.array([rows[-1, 2], rows[-1, 3], 1.0])
        # bearing of view a expressed in camera b: R_CbCa = R_CI R_0b^T R_0a R_IC
        rot = R_CI @ R_0k[kb].T @ R_0k[ka] @ R_IC @ bearing_a
        c = np.cross(rot, bearing_b)
        angles.append(np.degrees(np.arctan2(np.linalg.norm(c), float(rot @ bearing_b))))
    return float(np.median(angles)) if angles else 0.0
