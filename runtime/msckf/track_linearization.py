"""Feature tracks linearised at the filter's clone window, all tracks of one update in one numba call:
packing the tracks' observations at the window into flat arrays, and the kernels that triangulate, linearise,
project out the feature and gate each track. Shared by the MSCKF update and the SLAM delayed initialisation.

Done in one call per frame, the per-track steps leave the Python interpreter out of the per-track loop, which
dominated the filter's time per frame.

Packed layout: `ptr` (T+1,) offsets of each track's observations into `slots` (clone slot in the window,
oldest first), `uv` (pixels) and `xn` (normalised coordinates).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from runtime.msckf.camera_kernels import CameraParams, undistort_points
from runtime.msckf.config import MsckfConfig
from runtime.msckf.feature_db import Track
from runtime.msckf.measurement import (
    feature_intrinsics_jacobian,
    feature_jacobians,
    givens_left_nullspace,
    spd_mahalanobis,
)
from runtime.msckf.state import State
from runtime.msckf.state_helper import _CHI2_95
from runtime.msckf.triangulation import triangulate


def window_columns(state: State) -> tuple[np.ndarray, dict[int, int]]:
    """Covariance columns of (extrinsics, intrinsics, all clones) and each clone's offset into them (the
    calibration blocks are present only when estimated)."""
    cols: list[int] = []
    if state.idx_ext >= 0:
        cols.extend(range(state.idx_ext, state.idx_ext + 6))
    if state.idx_intr >= 0:
        cols.extend(range(state.idx_intr, state.idx_intr + 8))
    offset = {}
    for t in state.clone_times():
        c = state.clones[t]
        offset[t] = len(cols)
        cols.extend(range(c.idx, c.idx + 6))
    return np.asarray(cols, dtype=np.int64), offset


#: status codes of the kernels, per track
OK, NOT_LINEARIZED, NO_ROWS, CHI2_REJECTED = 0, 1, 2, 3


class WindowArrays:
    """The clone window as arrays: current and first-estimate poses, oldest first (the window_columns
    order), with each clone's slot by camera time."""

    def __init__(self, state: State) -> None:
        times = state.clone_times()
        clones = [state.clones[t] for t in times]
        self.slot = {t: j for j, t in enumerate(times)}
        self.R = np.array([c.R for c in clones])
        self.p = np.array([c.p for c in clones])
        self.R_fej = np.array([c.R_fej for c in clones])
        self.p_fej = np.array([c.p_fej for c in clones])


def pack_tracks(state: State, win: WindowArrays, tracks: list[Track], cam: CameraParams) -> tuple:
    """(ptr, slots, uv, xn) of the tracks' observations at the window's clones (see the module docstring).

    With online intrinsics xn is recomputed from the pixels with the state's current intrinsics (the
    database's were undistorted with older ones)."""
    slot = win.slot
    ptr = np.zeros(len(tracks) + 1, dtype=np.int64)
    slots: list[int] = []
    uv: list[np.ndarray] = []
    xn: list[np.ndarray] = []
    for i, tr in enumerate(tracks):
        js = [slot.get(t) for t in tr.t_ns]
        if None not in js:                      # the usual case: every observation is at a clone
            slots.extend(js)
            uv.extend(tr.uv)
            xn.extend(tr.xn)
        else:
            for k, j in enumerate(js):
                if j is not None:
                    slots.append(j)
                    uv.append(tr.uv[k])
                    xn.append(tr.xn[k])
        ptr[i + 1] = len(slots)
    n = len(slots)
    uv_a = np.array(uv, dtype=float).reshape(n, 2)
    if state.cam_params is not None:
        xn_a = undistort_points(cam.code, state.cam_params, uv_a)
    else:
        xn_a = np.array(xn, dtype=float).reshape(n, 2)
    return ptr, np.array(slots, dtype=np.int64), uv_a, xn_a


@njit(cache=True, nogil=True)
def _camera_pose(R: np.ndarray, p: np.ndarray, R_IC: np.ndarray, p_IC: np.ndarray, R_out: np.ndarray,
                 p_out: np.ndarray) -> None:
    """R_out = R R_IC, p_out = p + R p_IC (the camera pose of the clone (R, p); scalar loops)."""
    for j in range(3):
        for k in range(3):
            R_out[j, k] = R[j, 0] * R_IC[0, k] + R[j, 1] * R_IC[1, k] + R[j, 2] * R_IC[2, k]
        p_out[j] = p[j] + R[j, 0] * p_IC[0] + R[j, 1] * p_IC[1] + R[j, 2] * p_IC[2]


@njit(cache=True, nogil=True)
def linearize_packed(Rw: np.ndarray, pw: np.ndarray, Rfw: np.ndarray, pfw: np.ndarray, slots: np.ndarray,
                     uv: np.ndarray, xn: np.ndarray, R_IC: np.ndarray, p_IC: np.ndarray, code: int,
                     prm: np.ndarray, tri: np.ndarray, tri_iterations: int, fej_triangulation: bool,
                     has_ext: bool, has_intr: bool, ncol: int) -> tuple:
    """One track (its observations slots/uv/xn) triangulated from the current clone poses (Rw, pw: the
    window's, by slot) and linearised in the window_columns layout (extrinsics, intrinsics, clones).

    tri: [max_cond, min_dist, max_dist, max_baseline_ratio]. Returns (ok, p_O, p_lin, r (2m,), Hx (2m, ncol),
    Hf (2m, 3)); p_lin is the Jacobians' point (with fej_triangulation the one triangulated from the first
    estimates, when that succeeds)."""
    m = slots.shape[0]
    Rc = np.empty((m, 3, 3))
    pc = np.empty((m, 3))
    Rf = np.empty((m, 3, 3))
    pf = np.empty((m, 3))
    R_OC = np.empty((m, 3, 3))
    p_OC = np.empty((m, 3))
    for i in range(m):
        j = slots[i]
        Rc[i] = Rw[j]
        pc[i] = pw[j]
        Rf[i] = Rfw[j]
        pf[i] = pfw[j]
        _camera_pose(Rc[i], pc[i], R_IC, p_IC, R_OC[i], p_OC[i])
    p_lin = np.zeros(3)
    empty = (False, p_lin, p_lin, np.zeros(0), np.zeros((0, ncol)), np.zeros((0, 3)))
    if m < 2:
        return empty
    ok, p_O = triangulate(R_OC, p_OC, xn, tri[0], tri[1], tri[2], tri[3], tri_iterations)
    if not ok:
        return empty
    p_lin = p_O
    if fej_triangulation:
        for i in range(m):
            _camera_pose(Rf[i], pf[i], R_IC, p_IC, R_OC[i], p_OC[i])
        ok_f, p_f = triangulate(R_OC, p_OC, xn, tri[0], tri[1], tri[2], tri[3], tri_iterations)
        if ok_f:
            p_lin = p_f
    ok, r, Hc, He, Hf = feature_jacobians(Rc, pc, Rf, pf, uv, p_O, p_lin, R_IC, p_IC, code, prm)
    if not ok:
        return empty
    Hx = np.zeros((2 * m, ncol))
    o = 0
    if has_ext:
        Hx[:, 0:6] = He
        o = 6
    if has_intr:
        Hx[:, o:o + 8] = feature_intrinsics_jacobian(Rf, pf, p_lin, R_IC, p_IC, code, prm)
        o += 8
    for i in range(m):
        c = o + 6 * slots[i]
        Hx[2 * i:2 * i + 2, c:c + 6] = Hc[2 * i:2 * i + 2]
    return True, p_O, p_lin, r, Hx, Hf


@njit(cache=True, nogil=True)
def msckf_rows_packed(Rw: np.ndarray, pw: np.ndarray, Rfw: np.ndarray, pfw: np.ndarray, ptr: np.ndarray,
                      slots: np.ndarray, uv: np.ndarray, xn: np.ndarray, R_IC: np.ndarray, p_IC: np.ndarray,
                      code: int, prm: np.ndarray, tri: np.ndarray, tri_iterations: int,
                      fej_triangulation: bool, has_ext: bool, has_intr: bool, Pcc: np.ndarray, sigma: float,
                      chi2_multiplier: float, chi2_table: np.ndarray) -> tuple:
    """MSCKF rows of all packed tracks: each triangulated, linearised, projected onto the left nullspace of
    its feature Jacobian and chi-square gated against Pcc, the covariance of the window columns.

    Returns (status (T,) of OK / NOT_LINEARIZED / NO_ROWS / CHI2_REJECTED, H (rows, ncol), r (rows,)) with the
    accepted tracks' rows stacked in track order."""
    ntr = ptr.shape[0] - 1
    ncol = Pcc.shape[0]
    status = np.zeros(ntr, dtype=np.int64)
    cap = 0
    for t in range(ntr):
        cap += max(2 * (ptr[t + 1] - ptr[t]) - 3, 0)
    H = np.zeros((cap, ncol))
    r = np.zeros(cap)
    row = 0
    s2 = sigma * sigma
    for t in range(ntr):
        a, b = ptr[t], ptr[t + 1]
        ok, _, _, rt, Hx, Hf = linearize_packed(Rw, pw, Rfw, pfw, slots[a:b], uv[a:b], xn[a:b], R_IC, p_IC,
                                                code, prm, tri, tri_iterations, fej_triangulation, has_ext,
                                                has_intr, ncol)
        if not ok:
            status[t] = NOT_LINEARIZED
            continue
        Hx2, r2, _, _, _ = givens_left_nullspace(Hf, Hx, rt)
        k = Hx2.shape[0]
        if k == 0:
            status[t] = NO_ROWS
            continue
        S = Hx2 @ Pcc @ Hx2.T
        for i in range(k):
            S[i, i] += s2
        d2 = spd_mahalanobis(S, r2)
        if k <= chi2_table.shape[0]:
            q95 = chi2_table[k - 1]
        else:   # Wilson-Hilferty (relative error below 1e-4 beyond the table's 2000 degrees of freedom)
            c = 2.0 / (9.0 * k)
            q95 = k * (1.0 - c + 1.6448536269514722 * np.sqrt(c)) ** 3
        limit = chi2_multiplier * q95
        if not d2 < limit:
            status[t] = CHI2_REJECTED
            continue
        H[row:row + k] = Hx2
        r[row:row + k] = r2
        row += k
    return status, H[:row], r[:row]


@njit(cache=True, nogil=True)
def linearize_all_packed(Rw: np.ndarray, pw: np.ndarray, Rfw: np.ndarray, pfw: np.ndarray, ptr: np.ndarray,
                         slots: np.ndarray, uv: np.ndarray, xn: np.ndarray, R_IC: np.ndarray,
                         p_IC: np.ndarray, code: int, prm: np.ndarray, tri: np.ndarray, tri_iterations: int,
                         fej_triangulation: bool, has_ext: bool, has_intr: bool, ncol: int) -> tuple:
    """linearize_packed for every packed track: (ok (T,), p_O (T,3), p_lin (T,3), r (2N,), Hx (2N, ncol),
    Hf (2N, 3)), track t's rows at 2 ptr[t] .. 2 ptr[t+1] (zero when not ok)."""
    ntr = ptr.shape[0] - 1
    nobs = ptr[ntr]
    ok_all = np.zeros(ntr, dtype=np.bool_)
    p_all = np.zeros((ntr, 3))
    plin_all = np.zeros((ntr, 3))
    r_all = np.zeros(2 * nobs)
    Hx_all = np.zeros((2 * nobs, ncol))
    Hf_all = np.zeros((2 * nobs, 3))
    for t in range(ntr):
        a, b = ptr[t], ptr[t + 1]
        ok, p_O, p_lin, r, Hx, Hf = linearize_packed(Rw, pw, Rfw, pfw, slots[a:b], uv[a:b], xn[a:b], R_IC,
                                                     p_IC, code, prm, tri, tri_iterations, fej_triangulation,
                                                     has_ext, has_intr, ncol)
        if not ok:
            continue
        ok_all[t] = True
        p_all[t] = p_O
        plin_all[t] = p_lin
        r_all[2 * a:2 * b] = r
        Hx_all[2 * a:2 * b] = Hx
        Hf_all[2 * a:2 * b] = Hf
    return ok_all, p_all, plin_all, r_all, Hx_all, Hf_all


def tri_params(cfg: MsckfConfig) -> np.ndarray:
    """The triangulation thresholds as the kernels take them."""
    return np.array([cfg.tri_max_cond, cfg.tri_min_dist, cfg.tri_max_dist, cfg.tri_max_baseline_ratio])


def msckf_rows(state: State, tracks: list[Track], cfg: MsckfConfig, cam: CameraParams, Pcc: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(status, H, r) of msckf_rows_packed for `tracks` at the state's window (chi-square gated with
    cfg.chi2_multiplier; the tracks' 95 % quantiles from state_helper's table)."""
    win = WindowArrays(state)
    ptr, slots, uv, xn = pack_tracks(state, win, tracks, cam)
    return msckf_rows_packed(
        win.R, win.p, win.R_fej, win.p_fej, ptr, slots, uv, xn, state.R_IC, state.p_IC, cam.code,
        state.camera_params(cam.params), tri_params(cfg), int(cfg.tri_gn_iterations),
        cfg.use_fej and cfg.fej_triangulation, state.idx_ext >= 0, state.idx_intr >= 0, Pcc,
        float(cfg.sigma_pix), float(cfg.chi2_multiplier), _CHI2_95,
    )


def linearize_tracks(state: State, tracks: list[Track], cfg: MsckfConfig, cam: CameraParams) -> list:
    """Per track, None when it cannot be used, else (p_O, p_lin, r, Hx, Hf) of linearize_packed in the
    window_columns layout."""
    win = WindowArrays(state)
    ptr, slots, uv, xn = pack_tracks(state, win, tracks, cam)
    ncol = 6 * len(win.slot) + (6 if state.idx_ext >= 0 else 0) + (8 if state.idx_intr >= 0 else 0)
    ok, p_O, p_lin, r, Hx, Hf = linearize_all_packed(
        win.R, win.p, win.R_fej, win.p_fej, ptr, slots, uv, xn, state.R_IC, state.p_IC, cam.code,
        state.camera_params(cam.params), tri_params(cfg), int(cfg.tri_gn_iterations),
        cfg.use_fej and cfg.fej_triangulation, state.idx_ext >= 0, state.idx_intr >= 0, ncol,
    )
    out: list = []
    for t in range(len(tracks)):
        if not ok[t]:
            out.append(None)
            continue
        rows = slice(2 * ptr[t], 2 * ptr[t + 1])
        out.append((p_O[t], p_lin[t], r[rows], Hx[rows], Hf[rows]))
    return out
