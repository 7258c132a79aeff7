"""Time-stamped pose sequences (pure data, no file formats).

A `PoseTrajectory` holds poses T_WB (body B in world W) at int64 nanosecond stamps.
Optional per-pose velocity (in W) and IMU biases are carried for ground truth.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class PoseTrajectory:
    """Poses T_WB at stamps t_ns.

    Attributes:
        t_ns: (N,) int64 nanoseconds, strictly increasing.
        p: (N, 3) float64 positions p_WB in metres.
        R: (N, 3, 3) float64 rotations R_WB.
        v: optional (N, 3) velocities of B in W, m/s.
        bg: optional (N, 3) gyroscope biases, rad/s.
        ba: optional (N, 3) accelerometer biases, m/s^2.
    """

    t_ns: np.ndarray
    p: np.ndarray
    R: np.ndarray
    v: np.ndarray | None = None
    bg: np.ndarray | None = None
    ba: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.t_ns = np.asarray(self.t_ns, dtype=np.int64).reshape(-1)
        n = self.t_ns.shape[0]
        self.p = np.asarray(self.p, dtype=np.float64).reshape(n, 3)
        self.R = np.asarray(self.R, dtype=np.float64).reshape(n, 3, 3)
        for name in ("v", "bg", "ba"):
            arr = getattr(self, name)
            if arr is not None:
                setattr(self, name, np.asarray(arr, dtype=np.float64).reshape(n, 3))

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    @property
    def t_s(self) -> np.ndarray:
        """Stamps in float seconds relative to the first stamp (for math and plots)."""
        if len(self) == 0:
            return np.zeros(0)
        return (self.t_ns - self.t_ns[0]).astype(np.float64) * 1e-9

    @property
    def T(self) -> np.ndarray:
        """(N, 4, 4) homogeneous poses T_WB."""
        out = np.zeros((len(self), 4, 4))
        out[:, :3, :3] = self.R
        out[:, :3, 3] = self.p
        out[:, 3, 3] = 1.0
        return out

    def subset(self, index: np.ndarray) -> PoseTrajectory:
        """A new trajectory with the poses selected by a boolean mask or index array."""
        pick = lambda a: None if a is None else a[index]  # noqa: E731
        return PoseTrajectory(self.t_ns[index], self.p[index], self.R[index], pick(self.v),
                              pick(self.bg), pick(self.ba), dict(self.meta))

    def path_length(self) -> float:
        """Sum of distances between consecutive positions, metres."""
        if len(self) < 2:
            return 0.0
        return float(np.linalg.norm(np.diff(self.p, axis=0), axis=1).sum())
