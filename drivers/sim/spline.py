"""Uniform cubic B-splines on R^3 and SO(3) with closed-form derivatives (the simulator's motion).

A pose spline T_WI(t) = (R_WI(t), p_WI(t)) is C2 in position and C2 in rotation (cumulative
B-spline on SO(3)); velocity, acceleration (in W) and the body angular rate (in I) are exact, so
the IMU synthesised from it is exact up to float rounding.

Knots are uniform with spacing `dt_s`, starting at `t0_ns`. With control points c_0..c_{n-1},
segment i (t in [t0 + i dt, t0 + (i+1) dt)) blends c_i..c_{i+3}; the spline is defined on
[t0, t0 + (n-3) dt]. Control point k sits "near" time t0 + (k-1) dt.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from runtime.errors import ConfigError
from runtime.geometry.so3 import so3_exp, so3_log

# cumulative cubic basis: Btilde(u) = _C @ [1, u, u^2, u^3]
_C = (
    np.array([[6.0, 0.0, 0.0, 0.0], [5.0, 3.0, -3.0, 1.0], [1.0, 3.0, 3.0, -2.0], [0.0, 0.0, 0.0, 1.0]]) / 6.0
)


@dataclass
class SplineSample:
    """Spline state at a set of times (all in the world frame W unless noted).

    Attributes:
        p: (N,3) positions p_WI, m.   v: (N,3) velocities, m/s.   a: (N,3) accelerations, m/s^2.
        R: (N,3,3) rotations R_WI.    omega: (N,3) body angular rate in I, rad/s.
    """

    p: np.ndarray
    v: np.ndarray
    a: np.ndarray
    R: np.ndarray
    omega: np.ndarray


class PoseSpline:
    """C2 pose spline T_WI(t): cumulative cubic B-splines on positions and rotations.

    Args:
        t0_ns: time of the first knot, int64 ns.
        dt_s: knot spacing, s (> 0).
        control_p: (n,3) position control points (n >= 4), m.
        control_R: (n,3,3) rotation control points R_WI.
    """

    def __init__(self, t0_ns: int, dt_s: float, control_p: np.ndarray, control_R: np.ndarray) -> None:
        control_p = np.asarray(control_p, dtype=np.float64)
        control_R = np.asarray(control_R, dtype=np.float64)
        if not dt_s > 0:
            raise ConfigError(f"spline knot spacing must be > 0 s, got {dt_s}")
        if control_p.ndim != 2 or control_p.shape[1] != 3 or control_p.shape[0] < 4:
            raise ConfigError(f"need (n>=4, 3) position control points, got shape {control_p.shape}")
        if control_R.shape != (control_p.shape[0], 3, 3):
            raise ConfigError(
                f"need ({control_p.shape[0]}, 3, 3) rotation control points, got {control_R.shape}"
            )
        self.t0_ns = int(t0_ns)
        self.dt_s = float(dt_s)
        self.control_p = control_p
        self.control_R = control_R
        # relative rotations d_k = Log(R_{k-1}^T R_k), k = 1..n-1 (d_0 unused)
        rel = np.einsum("nji,njk->nik", control_R[:-1], control_R[1:])
        self._d = np.concatenate([np.zeros((1, 3)), so3_log(rel)], axis=0)

    @property
    def t_end_ns(self) -> int:
        """Last time at which the spline is defined, int64 ns."""
        return self.t0_ns + int(round((self.control_p.shape[0] - 3) * self.dt_s * 1e9))

    def _segment(self, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t_ns = np.asarray(t_ns, dtype=np.int64).reshape(-1)
        if t_ns.size and (t_ns.min() < self.t0_ns or t_ns.max() > self.t_end_ns):
            raise ConfigError(
                f"spline queried at [{t_ns.min()}, {t_ns.max()}] ns outside its span "
                f"[{self.t0_ns}, {self.t_end_ns}] ns"
            )
        s = (t_ns - self.t0_ns).astype(np.float64) * 1e-9 / self.dt_s
        n_seg = self.control_p.shape[0] - 3
        i = np.minimum(np.floor(s).astype(np.int64), n_seg - 1)
        return i, s - i

    def sample(self, t_ns: np.ndarray) -> SplineSample:
        """Positions, velocities, accelerations, rotations and body rates at int64 ns stamps."""
        i, u = self._segment(t_ns)
        dt = self.dt_s
        U = np.stack([np.ones_like(u), u, u * u, u**3], axis=1)
        dU = np.stack([np.zeros_like(u), np.ones_like(u), 2 * u, 3 * u * u], axis=1) / dt
        ddU = np.stack([np.zeros_like(u), np.zeros_like(u), 2 * np.ones_like(u), 6 * u], axis=1) / dt**2
        B, dB, ddB = U @ _C.T, dU @ _C.T, ddU @ _C.T  # (N, 4), column j = Btilde_j
        cp = self.control_p
        p = cp[i].copy()
        v = np.zeros_like(p)
        a = np.zeros_like(p)
        R = self.control_R[i].copy()
        omega = np.zeros_like(p)
        for j in (1, 2, 3):
            dp = cp[i + j] - cp[i + j - 1]
            p += B[:, j, None] * dp
            v += dB[:, j, None] * dp
            a += ddB[:, j, None] * dp
            d = self._d[i + j]
            A = so3_exp(B[:, j, None] * d)
            R = R @ A
            omega = np.einsum("nji,nj->ni", A, omega) + dB[:, j, None] * d
        return SplineSample(p=p, v=v, a=a, R=R, omega=omega)

    def pose(self, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(R_WI (N,3,3), p_WI (N,3)) at int64 ns stamps."""
        s = self.sample(t_ns)
        return s.R, s.p


def fit_pose_spline(
    t_ns: np.ndarray, p: np.ndarray, R: np.ndarray, dt_s: float = 0.1, smoothing: float = 1e-6
) -> PoseSpline:
    """Fit a PoseSpline to sampled poses T_WI (e.g. a trajectory file).

    Positions are fitted by linear least squares (with a small second-difference penalty
    `smoothing`, m^-2 scaled, to keep unobserved control points defined); rotation control points
    are the samples' rotations interpolated at each control point's time. The spline covers
    [t_ns[0], t_ns[-1]] (rounded down to whole knots).
    """
    t_ns = np.asarray(t_ns, dtype=np.int64)
    p = np.asarray(p, dtype=np.float64)
    R = np.asarray(R, dtype=np.float64)
    if t_ns.ndim != 1 or t_ns.size < 4 or np.any(np.diff(t_ns) <= 0):
        raise ConfigError("fitting a spline needs >= 4 strictly increasing stamps")
    span = (t_ns[-1] - t_ns[0]) * 1e-9
    n_seg = int(np.floor(span / dt_s))
    if n_seg < 1:
        raise ConfigError(f"trajectory spans {span:.3f} s, shorter than one knot ({dt_s} s)")
    n = n_seg + 3
    t0 = int(t_ns[0])
    s = (t_ns - t0) * 1e-9 / dt_s
    keep = s <= n_seg
    s, pk = s[keep], p[keep]
    i = np.minimum(np.floor(s).astype(np.int64), n_seg - 1)
    u = s - i
    U = np.stack([np.ones_like(u), u, u * u, u**3], axis=1)
    M = np.array([[1, 4, 1, 0], [-3, 0, 3, 0], [3, -6, 3, 0], [-1, 3, -3, 1]], dtype=np.float64) / 6.0
    W = U @ M  # plain (non-cumulative) basis weights of c_i..c_{i+3}
    A = np.zeros((s.size, n))
    for j in range(4):
        A[np.arange(s.size), i + j] += W[:, j]
    D = np.zeros((n - 2, n))
    for k in range(n - 2):
        D[k, k : k + 3] = (1.0, -2.0, 1.0)
    lhs = np.vstack([A, np.sqrt(smoothing * s.size) * D])
    rhs = np.vstack([pk, np.zeros((n - 2, 3))])
    ctrl_p, *_ = np.linalg.lstsq(lhs, rhs, rcond=None)
    t_ctrl = t0 + np.round((np.arange(n) - 1) * dt_s * 1e9).astype(np.int64)
    ctrl_R = interpolate_rotations(t_ns, R, np.clip(t_ctrl, t_ns[0], t_ns[-1]))
    return PoseSpline(t0, dt_s, ctrl_p, ctrl_R)


def interpolate_rotations(t_ns: np.ndarray, R: np.ndarray, t_query_ns: np.ndarray) -> np.ndarray:
    """Geodesic (slerp) interpolation of rotations sampled at increasing t_ns; clamps outside."""
    t_ns = np.asarray(t_ns, dtype=np.int64)
    tq = np.clip(np.asarray(t_query_ns, dtype=np.int64), t_ns[0], t_ns[-1])
    k = np.clip(np.searchsorted(t_ns, tq, side="right") - 1, 0, t_ns.size - 2)
    alpha = (tq - t_ns[k]).astype(np.float64) / (t_ns[k + 1] - t_ns[k]).astype(np.float64)
    rel = so3_log(np.einsum("nji,njk->nik", R[k], R[k + 1]))
    return R[k] @ so3_exp(alpha[:, None] * rel)


def interpolate_positions(t_ns: np.ndarray, p: np.ndarray, t_query_ns: np.ndarray) -> np.ndarray:
    """Linear interpolation of positions sampled at increasing t_ns; clamps outside."""
    t = (np.asarray(t_ns, dtype=np.int64) - t_ns[0]).astype(np.float64)
    tq = (np.asarray(t_query_ns, dtype=np.int64) - t_ns[0]).astype(np.float64)
    return np.stack([np.interp(tq, t, p[:, k]) for k in range(3)], axis=1)


__all__ = ["PoseSpline", "SplineSample", "fit_pose_spline", "interpolate_positions", "interpolate_rotations"]
