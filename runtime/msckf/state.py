"""Filter state: IMU, calibration, clone window, SLAM landmarks and their joint covariance.

Error-state layout (covariance order): IMU [dtheta, dp, dv, dbg, dba] (15) at 0, then the time offset (1)
and the extrinsics [dphi, dp_IC] (6) and the camera intrinsics [fx, fy, cx, cy, d0..d3] (8, additive) when
estimated, then clones (6 each) and landmarks (3 each) in
creation order. Rotations use right perturbations R = R_hat Exp(dtheta). First estimates (FEJ) are
kept here, never in the updaters.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from runtime.msckf.so3_kernels import exp3, normalize_rot


@dataclass
class Clone:
    """A stochastic clone of the IMU pose at a camera time t_cam_ns (pose T_OI at t_cam + t_d)."""

    t_cam_ns: int
    R: np.ndarray
    p: np.ndarray
    R_fej: np.ndarray
    p_fej: np.ndarray
    idx: int


@dataclass
class Landmark:
    """A SLAM landmark: global 3D position in O (anchor_t None) or anchored inverse depth
    [x/z, y/z, 1/z] in the camera of the clone at camera time anchor_t."""

    fid: int
    p: np.ndarray
    p_fej: np.ndarray
    idx: int
    fail_count: int = 0  #: updates in which it could not be projected; marginalised after two
    chi2_failures: int = 0  #: observations the chi-square gate refused (MsckfConfig.slam_max_chi2_failures)
    anchor_t: int | None = None


class State:
    """The joint state and covariance of the filter."""

    def __init__(self, R_IC: np.ndarray, p_IC: np.ndarray, t_d: float, calib_dt: bool, calib_ext: bool,
                 cam_params: np.ndarray | None = None) -> None:
        """cam_params: the camera's parameters [fx, fy, cx, cy, d0..d7] (`CameraParams.params`; 9 values for
        radtan are accepted) to estimate online (the first 8 become error states after the extrinsics); None:
        the intrinsics are fixed outside the state."""
        self.t_ns = 0                    # IMU-clock time of the IMU state, ns
        self.R = np.eye(3)
        self.p = np.zeros(3)
        self.v = np.zeros(3)
        self.bg = np.zeros(3)
        self.ba = np.zeros(3)
        self.R_fej = np.eye(3)
        self.p_fej = np.zeros(3)
        self.v_fej = np.zeros(3)
        self.R_IC = np.array(R_IC, dtype=float)
        self.p_IC = np.array(p_IC, dtype=float)
        self.t_d = float(t_d)            # t_imu = t_cam + t_d, s
        n = 15
        self.idx_dt = -1
        self.idx_ext = -1
        if calib_dt:
            self.idx_dt = n
            n += 1
        if calib_ext:
            self.idx_ext = n
            n += 6
        self.idx_intr = -1
        self.cam_params = None if cam_params is None else np.array(cam_params, dtype=float)
        if self.cam_params is not None:
            if self.cam_params.shape not in ((9,), (12,)):
                raise ValueError(f"cam_params must have 9 or 12 entries, got shape {self.cam_params.shape}")
            self.idx_intr = n
            n += 8
        self.P = np.zeros((n, n))
        self.clones: dict[int, Clone] = {}
        self.slam: dict[int, Landmark] = {}

    @property
    def size(self) -> int:
        return self.P.shape[0]

    def camera_params(self, fixed: np.ndarray) -> np.ndarray:
        """The intrinsics the measurement model uses: the state's estimate when calibrated online, else
        `fixed` (the camera's)."""
        return self.cam_params if self.cam_params is not None else fixed

    def add_variable(self, size: int, value_cov: np.ndarray, cross: np.ndarray) -> int:
        """Append `size` error states with covariance value_cov and cross-covariance cross (size, n)."""
        n = self.size
        P = np.empty((n + size, n + size))
        P[:n, :n] = self.P
        P[n:, :n] = cross
        P[:n, n:] = cross.T
        P[n:, n:] = value_cov
        self.P = P
        return n

    def remove_variable(self, idx: int, size: int) -> None:
        """Delete error states idx..idx+size (marginalisation) and shift the later indices."""
        self.remove_variables([(idx, size)])

    def remove_variables(self, blocks: list[tuple[int, int]]) -> None:
        """Delete several (idx, size) blocks of error states at once and shift the later indices."""
        if not blocks:
            return
        mask = np.ones(self.size, dtype=bool)
        for idx, size in blocks:
            mask[idx:idx + size] = False
        self.P = _submatrix(self.P, mask)
        shift = np.cumsum(~mask)            # removed entries at or before each index

        def moved(i: int) -> int:
            return i - int(shift[i])

        for c in self.clones.values():
            c.idx = moved(c.idx)
        for lm in self.slam.values():
            lm.idx = moved(lm.idx)
        if self.idx_dt >= 0:
            self.idx_dt = moved(self.idx_dt)
        if self.idx_ext >= 0:
            self.idx_ext = moved(self.idx_ext)
        if self.idx_intr >= 0:
            self.idx_intr = moved(self.idx_intr)

    def apply_correction(self, dx: np.ndarray) -> None:
        """x <- x (+) dx over the whole error state (FEJ untouched)."""
        self.R = normalize_rot(self.R @ exp3(dx[0:3]))
        self.p = self.p + dx[3:6]
        self.v = self.v + dx[6:9]
        self.bg = self.bg + dx[9:12]
        self.ba = self.ba + dx[12:15]
        if self.idx_dt >= 0:
            self.t_d += float(dx[self.idx_dt])
        if self.idx_ext >= 0:
            i = self.idx_ext
            self.R_IC = normalize_rot(self.R_IC @ exp3(dx[i:i + 3]))
            self.p_IC = self.p_IC + dx[i + 3:i + 6]
        if self.idx_intr >= 0:
            i = self.idx_intr
            self.cam_params[:8] = self.cam_params[:8] + dx[i:i + 8]
        # all clones in one kernel call, all landmarks in one array sum (each keeps a row of the result)
        clones = list(self.clones.values())
        if clones:
            idx = np.fromiter((c.idx for c in clones), dtype=np.int64, count=len(clones))
            Rs = np.array([c.R for c in clones])
            ps = np.array([c.p for c in clones])
            _correct_clones(Rs, ps, idx, dx)
            for k, c in enumerate(clones):
                c.R, c.p = Rs[k], ps[k]
        lms = list(self.slam.values())
        if lms:
            idx = np.fromiter((lm.idx for lm in lms), dtype=np.int64, count=len(lms))
            new_p = np.array([lm.p for lm in lms]) + dx[idx[:, None] + _XYZ]
            for k, lm in enumerate(lms):
                lm.p = new_p[k]

    def clone_times(self) -> list[int]:
        """Camera times of the clones, oldest first."""
        return sorted(self.clones)


_XYZ = np.arange(3)


@njit(cache=True, nogil=True)
def _correct_clones(Rs: np.ndarray, ps: np.ndarray, idx: np.ndarray, dx: np.ndarray) -> None:
    """Clone k's pose R_k <- R_k Exp(dx[i:i+3]), p_k <- p_k + dx[i+3:i+6], i = idx[k] (in place). The clones
    are short-lived: Exp keeps R orthonormal to ~1e-15 without renormalising."""
    for k in range(idx.shape[0]):
        i = idx[k]
        E = exp3(dx[i:i + 3])
        R = Rs[k].copy()
        for a in range(3):
            for b in range(3):
                Rs[k, a, b] = R[a, 0] * E[0, b] + R[a, 1] * E[1, b] + R[a, 2] * E[2, b]
            ps[k, a] += dx[i + 3 + a]


def _submatrix(P: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """P[keep][:, keep] for a boolean mask, copied block by block over the mask's contiguous runs (a few
    removed blocks leave a few runs: slice copies instead of a gather of every entry)."""
    edges = np.flatnonzero(np.diff(np.concatenate(([0], keep.astype(np.int8), [0]))))
    runs = list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))
    m = int(keep.sum())
    out = np.empty((m, m))
    oi = 0
    for a, b in runs:
        oj = 0
        for c, d in runs:
            out[oi:oi + b - a, oj:oj + d - c] = P[a:b, c:d]
            oj += d - c
        oi += b - a
    return out
