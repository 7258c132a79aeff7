"""Alignment of an estimated trajectory to a reference: SE(3), Sim(3), position+yaw (4-DoF), none.

All methods minimise sum_i || p_ref_i - (s R p_est_i + t) ||^2 over associated positions:
- "se3": R in SO(3), t, s = 1 (Umeyama 1991 without scale; evo `-a`),
- "sim3": R, t and scale s (Umeyama with scale; evo `-as`),
- "posyaw": R a rotation about the gravity axis z only, t, s = 1 (the 4-DoF gauge of
  visual-inertial odometry, as OpenVINS' ov_eval "posyaw"; evo has no such mode),
- "none": identity.
The aligned trajectory has poses T_WB' = [sR | t] T_WB (rotations R R_WB, positions sR p + t).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from runtime.errors import TrajectoryError
from runtime.geometry.se3 import yaw_translation_fit
from runtime.geometry.trajectory import PoseTrajectory

METHODS: tuple[str, ...] = ("se3", "sim3", "posyaw", "none")


@dataclass(frozen=True)
class Alignment:
    """A similarity x -> s R x + t mapping the estimate's world into the reference's.

    Attributes:
        R: (3, 3) rotation, t: (3,) translation in metres, s: scale (1 unless "sim3"),
        method: the method that produced it.
    """

    R: np.ndarray
    t: np.ndarray
    s: float
    method: str

    def apply(self, traj: PoseTrajectory) -> PoseTrajectory:
        """The trajectory mapped by this alignment (velocities rotated and scaled, biases kept)."""
        p = self.s * traj.p @ self.R.T + self.t
        R = np.einsum("ij,njk->nik", self.R, traj.R)
        v = None if traj.v is None else self.s * traj.v @ self.R.T
        return PoseTrajectory(traj.t_ns.copy(), p, R, v, traj.bg, traj.ba, dict(traj.meta))

    def as_dict(self) -> dict:
        """JSON-ready fields (R row-major, yaw about z in degrees)."""
        return {"method": self.method, "scale": float(self.s), "translation_m": self.t.tolist(),
                "rotation": self.R.tolist(),
                "yaw_deg": float(np.degrees(np.arctan2(self.R[1, 0], self.R[0, 0])))}


def _check_points(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.ndim != 2 or src.shape[1] != 3 or src.shape != dst.shape:
        raise TrajectoryError(f"alignment needs two (N, 3) point sets of equal shape, got {src.shape} "
                              f"and {dst.shape}")
    if not (np.all(np.isfinite(src)) and np.all(np.isfinite(dst))):
        raise TrajectoryError("alignment points hold NaN or Inf")
    return src, dst


def umeyama(src: np.ndarray, dst: np.ndarray,
            with_scale: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares (R, t, s) with dst ~ s R src + t (Umeyama, PAMI 1991, eqs. 34-43).

    Args:
        src, dst: (N, 3) corresponding points, metres.
        with_scale: estimate s; otherwise s = 1.

    Raises:
        TrajectoryError: fewer than 3 points or collinear/degenerate configuration.
    """
    src, dst = _check_points(src, dst)
    n = src.shape[0]
    if n < 3:
        raise TrajectoryError(f"alignment needs at least 3 associated poses, got {n}")
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    xs, xd = src - mu_s, dst - mu_d
    var_s = float(np.sum(xs * xs)) / n
    cov = xd.T @ xs / n
    U, D, Vt = np.linalg.svd(cov)
    if np.count_nonzero(D > np.finfo(float).eps) < 2:
        raise TrajectoryError("degenerate point configuration (collinear or static): cannot align")
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0.0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    s = float(np.trace(np.diag(D) @ S) / var_s) if with_scale else 1.0
    t = mu_d - s * R @ mu_s
    return R, t, s


def posyaw(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares yaw rotation about z and translation with dst ~ Rz(yaw) src + t
    (`runtime.geometry.se3.yaw_translation_fit`, closed form).

    Raises:
        TrajectoryError: no horizontal extent (yaw unobservable) or no points.
    """
    src, dst = _check_points(src, dst)
    if src.shape[0] < 2:
        raise TrajectoryError(f"position+yaw alignment needs at least 2 associated poses, got {src.shape[0]}")
    R, t, strength = yaw_translation_fit(src, dst)
    if strength < 1e-12 * max(1.0, float(np.sum((src[:, :2] - src[:, :2].mean(axis=0)) ** 2))):
        raise TrajectoryError("no horizontal motion: yaw alignment is unobservable")
    return R, t


def align(est: PoseTrajectory, ref: PoseTrajectory, method: str = "se3",
          n_first: int | None = None) -> tuple[PoseTrajectory, Alignment]:
    """Align associated trajectories (equal length, pose i of `est` matching pose i of `ref`).

    Args:
        est, ref: associated trajectories (see `associate`).
        method: "se3", "sim3", "posyaw" or "none".
        n_first: fit on the first n poses only (all when None), apply to all.

    Returns:
        (aligned estimate, the Alignment).
    """
    if method not in METHODS:
        raise TrajectoryError(f"unknown alignment {method!r}; expected one of {', '.join(METHODS)}")
    if len(est) != len(ref):
        raise TrajectoryError(f"alignment needs associated trajectories, got {len(est)} and {len(ref)} poses")
    k = len(est) if n_first is None or n_first < 0 else min(int(n_first), len(est))
    src, dst = est.p[:k], ref.p[:k]
    if method == "none":
        a = Alignment(np.eye(3), np.zeros(3), 1.0, method)
    elif method == "posyaw":
        R, t = posyaw(src, dst)
        a = Alignment(R, t, 1.0, method)
    else:
        R, t, s = umeyama(src, dst, with_scale=method == "sim3")
        a = Alignment(R, t, s, method)
    return a.apply(est), a
