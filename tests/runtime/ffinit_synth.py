"""Synthetic start-up windows with exact ground truth for the feed-forward initializer tests.

The truth is built from closed-form motion (no IMU integration): preintegrated terms follow from
p_I0Ii = dt v0 - 0.5 dt^2 g + dp (paper eq. 2) with g pointing up, expressed in I0.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from runtime.ffinit.window import ImageObservations, InitWindow

G0 = 9.81
R_IC_EUROC_RAW = np.array([[0.0148655, -0.9998809, 0.0041403],
                           [0.9995572, 0.0149672, 0.0257155],
                           [-0.0257744, 0.0037562, 0.9996607]])
P_IC_EUROC = np.array([-0.0216401, -0.0646770, 0.0098107])


def _orthonormalize(R: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(R)
    return u @ vt


R_IC_EUROC = _orthonormalize(R_IC_EUROC_RAW)


@dataclass
class Truth:
    scale: float
    v0_I0: np.ndarray
    g_I0: np.ndarray
    R_WI: np.ndarray  # (N,3,3)
    p_WI: np.ndarray  # (N,3)
    v_W: np.ndarray  # (N,3)


def motion(kind: str):
    """Closed-form p_WI(t), v_W(t), R_WI(t) for a motion kind."""
    if kind in ("general", "tumbling"):   # tumbling: turning about all three axes (hand-eye observable)
        w = np.array([2.1, 2.7, 1.7])
        amp = np.array([0.6, 0.5, 0.3])
        phase = np.array([0.3, 1.1, 2.0])
        p = lambda t: amp * np.sin(w * t + phase)  # noqa: E731
        v = lambda t: amp * w * np.cos(w * t + phase)  # noqa: E731
        if kind == "general":
            R = lambda t: Rotation.from_rotvec(  # noqa: E731
                [0.25 * np.sin(1.3 * t), 0.4 * t, 0.15 * np.cos(0.9 * t)]).as_matrix()
        else:
            R = lambda t: Rotation.from_rotvec(  # noqa: E731
                [0.5 * np.sin(2.3 * t), 0.6 * t, 0.4 * np.cos(1.7 * t) - 0.4]).as_matrix()
    elif kind == "constant_velocity":
        vel = np.array([0.5, 0.2, 0.05])
        p = lambda t: vel * t  # noqa: E731
        v = lambda t: vel + 0 * t  # noqa: E731
        R = lambda t: np.eye(3)  # noqa: E731
    elif kind == "pure_rotation":
        p = lambda t: np.zeros(3)  # noqa: E731
        v = lambda t: np.zeros(3)  # noqa: E731
        R = lambda t: Rotation.from_rotvec([0.3 * t, 0.6 * t, 0.1 * t]).as_matrix()  # noqa: E731
    else:
        raise ValueError(kind)
    return p, v, R


def make_window(kind: str = "general", n_images: int = 5, spacing: float = 0.2, points: int = 80,
                scale: float = 2.5, rot_noise_deg: float = 0.0, depth_noise: float = 0.0,
                outlier_fraction: float = 0.0, seed: int = 0) -> tuple[InitWindow, Truth]:
    rng = np.random.default_rng(seed)
    p, v, R = motion(kind)
    ts = np.arange(n_images) * spacing
    R_WI = np.stack([R(t) for t in ts])
    p_WI = np.stack([p(t) for t in ts])
    v_W = np.stack([v(t) for t in ts])
    R_I0W = R_WI[0].T
    g_I0 = R_I0W @ np.array([0.0, 0.0, G0])
    v0 = R_I0W @ v_W[0]
    R_WC = R_WI @ R_IC_EUROC
    p_WC = p_WI + R_WI @ P_IC_EUROC
    R_C0W, p_C0W = R_WC[0].T, -R_WC[0].T @ p_WC[0]
    images, R_I0Ii, dp, dv = [], [], [], []
    for i, t in enumerate(ts):
        R_I0Ii.append(R_I0W @ R_WI[i])
        p_I0Ii = R_I0W @ (p_WI[i] - p_WI[0])
        dp.append(p_I0Ii - t * v0 + 0.5 * t * t * g_I0)
        dv.append(R_I0W @ (v_W[i] - v_W[0]) + g_I0 * t)
        z = rng.uniform(-0.6, 0.6, size=(points, 2))
        d = rng.uniform(1.5, 6.0, size=points)
        R_C0Ci = R_C0W @ R_WC[i]
        if rot_noise_deg > 0 and i > 0:
            R_C0Ci = R_C0Ci @ Rotation.from_rotvec(
                rng.normal(size=3) * np.radians(rot_noise_deg) / np.sqrt(3)).as_matrix()
        d_obs = d * np.exp(rng.normal(0, depth_noise, points)) if depth_noise else d.copy()
        if outlier_fraction > 0:  # grossly wrong depths (boundaries, reflections, moving objects)
            bad = rng.random(points) < outlier_fraction
            d_obs[bad] *= rng.uniform(1.8, 4.0, bad.sum()) ** rng.choice([-1, 1], bad.sum())
        p_C0Ci = R_C0W @ p_WC[i] + p_C0W
        images.append(ImageObservations(z=z, depth=d_obs / scale, conf=rng.uniform(1.0, 3.0, points),
                                        R_C0Ci=_orthonormalize(R_C0Ci), p_C0Ci=p_C0Ci / scale))
    Z = np.zeros((n_images, 3, 3))
    J_v_ba, J_p_ba = accel_bias_jacobians(R, ts)
    window = InitWindow(
        t_ns=(ts * 1e9).astype(np.int64), images=images, dt=ts, R_I0Ii=np.stack(R_I0Ii),
        dp=np.stack(dp), dv=np.stack(dv), J_R_bg=Z.copy(), J_p_bg=Z.copy(), J_p_ba=J_p_ba,
        J_v_bg=Z.copy(), J_v_ba=J_v_ba, R_IC=R_IC_EUROC, p_IC=P_IC_EUROC)
    return window, Truth(scale, v0, g_I0, R_WI, p_WI, v_W)


def accel_bias_jacobians(R, ts: np.ndarray, h: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """d dv_i / d ba = -int_0^t R_I0I ds and d dp_i / d ba = -int_0^t int_0^s R_I0I (trapezoid, step h)."""
    t = np.arange(0.0, ts[-1] + h / 2, h)
    R0T = R(0.0).T
    Rt = np.stack([R0T @ R(tk) for tk in t])
    Jv = -np.concatenate([np.zeros((1, 3, 3)), np.cumsum(0.5 * h * (Rt[1:] + Rt[:-1]), axis=0)])
    Jp = np.concatenate([np.zeros((1, 3, 3)), np.cumsum(0.5 * h * (Jv[1:] + Jv[:-1]), axis=0)])
    idx = np.rint(ts / h).astype(int)
    return Jv[idx], Jp[idx]


def imu_samples(kind: str, t_end: float, rate_hz: float = 1000.0, bg: np.ndarray | None = None,
                ba: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Noise-free IMU samples (t_ns, gyro, accel) of a motion kind from -0.05 s to t_end + 0.05 s.

    Angular rate from central differences of the closed-form rotation (h = 1e-5 s), specific force
    from central differences of the closed-form velocity: a_I = R_WI^T (a_W + g0 e_z).
    """
    p, v, R = motion(kind)
    t = np.arange(-0.05, t_end + 0.05, 1.0 / rate_hz)
    h = 1e-5
    gyro, accel = [], []
    for tk in t:
        Rk = R(tk)
        dR = (R(tk + h) - R(tk - h)) / (2 * h)
        W = Rk.T @ dR
        gyro.append([W[2, 1], W[0, 2], W[1, 0]])
        a_W = (v(tk + h) - v(tk - h)) / (2 * h)
        accel.append(Rk.T @ (a_W + np.array([0.0, 0.0, G0])))
    gyro = np.asarray(gyro) + (0 if bg is None else bg)
    accel = np.asarray(accel) + (0 if ba is None else ba)
    return np.round(t * 1e9).astype(np.int64), gyro, accel


@dataclass
class OffRayObservations(ImageObservations):
    """Observations some of whose DA3 points lie off their pixel's ray: the point is placed along
    z + ray_offset (a point-map error), not along the ray of its normalized coordinate z.

    A wrong depth along the pixel's own ray is no outlier for the point system: the row still vanishes
    at the true state (see test_wrong_depths_along_the_ray_only_reweight_the_rows).
    """

    ray_offset: np.ndarray
    """(M, 2) normalized-coordinate offset of each point's ray; zero for a good point."""

    @property
    def points_C0(self) -> np.ndarray:
        zt = np.column_stack([self.z + self.ray_offset, np.ones(len(self.z))])
        return (self.depth[:, None] * zt) @ self.R_C0Ci.T + self.p_C0Ci


def with_off_ray_points(window: InitWindow, fraction: float, seed: int,
                        offset: tuple[float, float] = (0.02, 0.05)) -> tuple[InitWindow, np.ndarray]:
    """The window with `fraction` of the points of images 1.. moved off their rays by |offset| in
    [offset[0], offset[1]] (normalized coordinates, 1.1-2.9 deg by default) in a random direction.
    Returns the window (images replaced) and the (K,) outlier mask in build_system's point order."""
    rng = np.random.default_rng(1000 + seed)
    images, masks = [window.images[0]], []
    for obs in window.images[1:]:
        m = len(obs.z)
        bad = rng.random(m) < fraction
        ang = rng.uniform(0.0, 2 * np.pi, m)
        mag = np.where(bad, rng.uniform(*offset, m), 0.0)
        images.append(OffRayObservations(obs.z, obs.depth, obs.conf, obs.R_C0Ci, obs.p_C0Ci,
                                         np.column_stack([np.cos(ang), np.sin(ang)]) * mag[:, None]))
        masks.append(bad)
    window.images = images
    return window, np.concatenate(masks)
