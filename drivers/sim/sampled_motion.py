"""Motion given by sampled poses (a real ground truth): interpolated T_WI(t)."""

from __future__ import annotations

import numpy as np

from drivers.sim.spline import interpolate_positions, interpolate_rotations
from runtime.errors import ConfigError
from runtime.geometry.trajectory import PoseTrajectory


class SampledMotion:
    """T_WI(t) from a PoseTrajectory: linear positions, geodesic rotations between samples.

    Used by the EuRoC-trajectory mode, where images are rendered along the real ground truth
    (sampled at 200 Hz, so linear interpolation is accurate to well below a millimetre).
    """

    def __init__(self, trajectory: PoseTrajectory) -> None:
        if len(trajectory) < 2:
            raise ConfigError("a sampled motion needs at least two poses")
        self.trajectory = trajectory
        self.t0_ns = int(trajectory.t_ns[0])
        self.t_end_ns = int(trajectory.t_ns[-1])

    def pose(self, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(R_WI (N,3,3), p_WI (N,3)) at int64 ns stamps inside the sampled span."""
        t_ns = np.asarray(t_ns, dtype=np.int64).reshape(-1)
        if t_ns.size and (t_ns.min() < self.t0_ns or t_ns.max() > self.t_end_ns):
            raise ConfigError(
                f"motion queried at [{t_ns.min()}, {t_ns.max()}] ns outside the ground truth "
                f"[{self.t0_ns}, {self.t_end_ns}] ns"
            )
        tr = self.trajectory
        return interpolate_rotations(tr.t_ns, tr.R, t_ns), interpolate_positions(tr.t_ns, tr.p, t_ns)

    def velocity(self, t_ns: np.ndarray) -> np.ndarray:
        """(N,3) velocity in W, m/s: the trajectory's own v when present, else central differences."""
        tr = self.trajectory
        t_ns = np.asarray(t_ns, dtype=np.int64).reshape(-1)
        v = tr.v if tr.v is not None else finite_difference_velocity(tr.t_ns, tr.p)
        return interpolate_positions(tr.t_ns, v, t_ns)


def finite_difference_velocity(t_ns: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(N,3) velocities from positions by (non-uniform) central differences, m/s."""
    t = (np.asarray(t_ns, np.int64) - t_ns[0]).astype(np.float64) * 1e-9
    return np.stack([np.gradient(p[:, k], t) for k in range(3)], axis=1)
