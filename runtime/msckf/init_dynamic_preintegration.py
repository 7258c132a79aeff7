"""IMU preintegration over the dynamic initializer's keyframes (biases held at a guess)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from runtime.imu import Preintegration, Preintegrator


@dataclass
class KeyframeImu:
    """Preintegrated IMU terms of the keyframes (IMU clock), all relative to the first keyframe's frame I0.

    Attributes:
        between: K-1 preintegrations between neighbouring keyframes (k to k+1).
        R_0k: (K, 3, 3) R_{I0 Ik} (identity for k = 0).
        dt_0k: (K,) time since the first keyframe, s.
        dp_0k: (K, 3) gravity-free displacement from I0, in I0, m (Preintegration.dp).
        dv_0k: (K, 3) gravity-free velocity change from I0, in I0, m/s (Preintegration.dv).
    """

    between: list[Preintegration]
    R_0k: np.ndarray
    dt_0k: np.ndarray
    dp_0k: np.ndarray
    dv_0k: np.ndarray


def preintegrate_keyframes(
    t_ns: np.ndarray,
    gyro: np.ndarray,
    accel: np.ndarray,
    t_kf_ns: np.ndarray,
    bg: np.ndarray,
    ba: np.ndarray,
    gyro_density: float,
    accel_density: float,
) -> KeyframeImu:
    """Preintegrate from the first keyframe to each one and between neighbours.

    Args:
        t_ns: (N,) int64 IMU sample times, ns.  gyro: (N, 3) rad/s.  accel: (N, 3) m/s^2 (specific
            force in I).
        t_kf_ns: (K,) int64 keyframe times on the IMU clock, ns, inside the samples' span.
        bg, ba: (3,) biases the terms are integrated at, rad/s and m/s^2.
        gyro_density, accel_density: continuous white-noise densities (rad/s/sqrt(Hz), m/s^2/sqrt(Hz))
            for the preintegration covariances.

    Raises:
        DataError: when the IMU samples do not cover an interval (from Preintegrator.integrate).
    """
    pre = Preintegrator(bg, ba, gyro_density, accel_density)
    from_first = [pre.integrate(t_ns, gyro, accel, int(t_kf_ns[0]), int(t)) for t in t_kf_ns[1:]]
    between = [
        pre.integrate(t_ns, gyro, accel, int(t0), int(t1))
        for t0, t1 in zip(t_kf_ns[:-1], t_kf_ns[1:], strict=True)
    ]
    return KeyframeImu(
        between=between,
        R_0k=np.stack([np.eye(3)] + [p.dR for p in from_first]),
        dt_0k=np.array([0.0] + [p.dt for p in from_first]),
        dp_0k=np.stack([np.zeros(3)] + [p.dp for p in from_first]),
        dv_0k=np.stack([np.zeros(3)] + [p.dv for p in from_first]),
    )
