"""Factors of the submap graph (paper Sec. V.C, eq. graphres): odometry, point groups, scale links.

Frames: S_j = the centre camera of submap j, M = the map frame (gravity-aligned, z up).
Node states are Q_j = T_MS_j and the residual log-depth scale lambda_j (see `graph.py`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from runtime.errors import EstimatorError


class GraphError(EstimatorError, ValueError):
    """The submap graph was given bad input (unknown node, malformed pose or points, bad sigma)."""


def check_pose(T: np.ndarray, name: str, tol: float = 1e-6) -> np.ndarray:
    """`T` as a float64 (4,4) rigid transform (orthonormal rotation with det +1, last row 0 0 0 1)."""
    T = np.array(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise GraphError(f"{name} must be a finite (4,4) pose, got shape {T.shape}")
    R = T[:3, :3]
    if (np.abs(R.T @ R - np.eye(3)).max() > tol or abs(np.linalg.det(R) - 1.0) > tol
            or np.abs(T[3] - [0.0, 0.0, 0.0, 1.0]).max() > 0.0):
        raise GraphError(f"{name} is not a rigid transform (bad rotation or last row)")
    return T


@dataclass(frozen=True)
class OdometryFactor:
    """r_o = Log(Z_ab^-1 Q_a^-1 Q_b): the VIO pose Z_ab = T_S_aS_b of centre b relative to centre a."""

    a: int
    b: int
    Z_ab: np.ndarray
    """(4,4) T_S_aS_b from the filter (metres)."""

    def as_dict(self) -> dict:
        return {"a": self.a, "b": self.b, "Z_ab": self.Z_ab.tolist()}


@dataclass(frozen=True)
class PointGroup:
    """r_k = Q_a(e^lambda_a p_ak) - Q_b(e^lambda_b p_bk): K corresponding points, weighted 1/K in the sum."""

    a: int
    b: int
    p_a: np.ndarray
    """(K,3) points in S_a without lambda_a (metres)."""
    p_b: np.ndarray
    """(K,3) the same points in S_b without lambda_b (metres)."""
    adjacent: bool
    """True for consecutive submaps, False for a verified revisit."""

    @property
    def n(self) -> int:
        return int(len(self.p_a))

    def as_dict(self, include_points: bool = False) -> dict:
        out = {"a": self.a, "b": self.b, "n": self.n, "adjacent": self.adjacent}
        if include_points:
            out["p_a"] = self.p_a.tolist()
            out["p_b"] = self.p_b.tolist()
        return out


@dataclass(frozen=True)
class ScaleFactor:
    """r_s = (lambda_b - lambda_a - kappa) / sigma (eq. shared, or a verified revisit's depth ratio)."""

    a: int
    b: int
    kappa: float
    sigma: float
    kind: str
    """"shared", "overlap" or "revisit" (informational)."""

    def as_dict(self) -> dict:
        return {"a": self.a, "b": self.b, "kappa": self.kappa, "sigma": self.sigma, "kind": self.kind}
