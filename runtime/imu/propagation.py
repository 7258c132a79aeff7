"""Propagation of a full navigation state (R_WI, p_WI, v_WI) with gravity, by RK4.

Used by tests and the simulator's checks as an independent reference for preintegration.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from runtime.errors import EstimatorError
from runtime.events import ImuSample
from runtime.geometry.checks import GeometryError, as_matrices
from runtime.geometry.trajectory import PoseTrajectory
from runtime.imu.kernels import nb_integrate_state_rk4
from runtime.imu.samples import ImuArrays, as_imu_arrays


def integrate_state(R_WI: np.ndarray, p: np.ndarray, v: np.ndarray,
                    samples: Sequence[ImuSample] | ImuArrays, g: float = 9.81,
                    bg: np.ndarray | None = None, ba: np.ndarray | None = None) -> PoseTrajectory:
    """The states T_WI (with v) at every sample stamp, starting from (R_WI, p, v) at the first one.

    World W is z-up with gravitational acceleration (0, 0, -g) m/s^2. `samples` are ImuSample-like
    objects or (t_ns, gyro, accel) arrays; biases (default zero) are subtracted. The measurements
    are linear between samples; classical RK4 with R projected onto SO(3) after each step.
    """
    t_ns, gyro, accel = as_imu_arrays(samples)
    if t_ns.size == 0:
        raise EstimatorError("integrate_state needs at least one IMU sample")
    try:
        R0 = as_matrices(R_WI, "R_WI").reshape(3, 3)
    except (GeometryError, ValueError) as exc:
        raise EstimatorError(f"R_WI must be a (3, 3) rotation: {exc}") from exc
    state = []
    for name, x in (("p", p), ("v", v), ("bg", bg), ("ba", ba)):
        a = np.zeros(3) if x is None else np.asarray(x, dtype=np.float64)
        if a.shape != (3,) or not np.all(np.isfinite(a)):
            raise EstimatorError(f"{name} must be a finite (3,) vector, got {a!r}")
        state.append(a)
    p0, v0, bg0, ba0 = state
    t_s = (t_ns - t_ns[0]).astype(np.float64) * 1e-9
    Rs, ps, vs = nb_integrate_state_rk4(t_s, gyro - bg0, accel - ba0, R0, p0, v0,
                                        np.array([0.0, 0.0, -float(g)]))
    return PoseTrajectory(t_ns, ps, Rs, v=vs)
