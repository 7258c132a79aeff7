"""A synthetic rig turning in place among far points: feature tracks (ids, normalized xy) and the gyro, with
a known camera-IMU rotation; for the model-free rig checks and bring-up."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

R_IC_SYN = Rotation.from_rotvec([0.3, -1.2, 0.5]).as_matrix()


def turning(t: float) -> np.ndarray:
    """A turn about changing axes (rad/s, camera frame)."""
    return np.array([0.4 * np.sin(1.3 * t), 0.5 * np.cos(0.9 * t), 0.3])


def synthetic_rig_events(R_IC, w_C, seconds=12.0, cam_hz=20, imu_hz=200, nan_at_s=None, imu_from_s=0.0):
    """Events (time order) of a camera turning at w_C(t) (rad/s, camera frame) in place among 400 far
    points, and its gyro R_IC w_C(t): ("imu", t_ns, gyro) and ("tracks", t_ns, ids, xy)."""
    from runtime.geometry import so3_exp

    rng = np.random.default_rng(0)
    X = rng.normal(size=(400, 3))
    X /= np.linalg.norm(X, axis=1, keepdims=True)
    step = 1e-3
    R, Rs = np.eye(3), []
    for k in range(int(seconds / step) + 1):      # R_C0C(t), integrated finely
        Rs.append(R)
        R = R @ so3_exp(w_C(k * step) * step)
    ev = []
    for k in range(int(seconds * cam_hz)):
        t = k / cam_hz
        p = X @ Rs[int(round(t / step))]          # R_CC0 X
        vis = np.flatnonzero(p[:, 2] > 0.3)
        ev.append((t, 1, "tracks", int(round(t * 1e9)), vis, p[vis, :2] / p[vis, 2:]))
    for k in range(int(seconds * imu_hz)):
        t = k / imu_hz
        g = np.array([np.nan, 0, 0]) if nan_at_s is not None and abs(t - nan_at_s) < 1e-9 else R_IC @ w_C(t)
        if t >= imu_from_s:
            ev.append((t, 0, "imu", int(round(t * 1e9)), g))
    return [e[2:] for e in sorted(ev, key=lambda e: (e[0], e[1]))]


