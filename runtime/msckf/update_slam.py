"""SLAM landmarks: batched updates with the newest clone, delayed initialisation from long tracks
(OpenVINS UpdaterSLAM structure; global 3D landmarks)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from runtime.msckf.camera_kernels import CameraParams
from runtime.msckf.config import MsckfConfig
from runtime.msckf.feature_db import Track
from runtime.msckf.measurement import feature_jacobians
from runtime.msckf.state import State
from runtime.msckf.state_helper import chi2_95, compress, ekf_update, initialize_landmark
from runtime.msckf.update_msckf import track_arrays, triangulate_track, window_columns


@dataclass
class SlamUpdateStats:
    """Counts of the SLAM stage of one frame."""

    updated: int = 0
    chi2_rejected: int = 0
    initialized: int = 0
    init_failed: int = 0


@njit(cache=True, nogil=True)
def slam_rows(P: np.ndarray, cidx: int, eidx: int, lidx: np.ndarray, Rc: np.ndarray, pc: np.ndarray,
              Rf: np.ndarray, pf: np.ndarray, uv: np.ndarray, lp: np.ndarray, lfej: np.ndarray,
              R_IC: np.ndarray, p_IC: np.ndarray, code: int, prm: np.ndarray, sigma: float) -> tuple:
    """Residuals, Jacobians and Mahalanobis distances of k landmarks seen by one clone.

    P: full covariance; cidx/eidx: clone and extrinsics columns (eidx < 0: none); lidx (k,) landmark columns.
    Returns ok (k,), d2 (k,), r (k,2), Hc (k,2,6), He (k,2,6), Hf (k,2,3).
    """
    k = lidx.shape[0]
    ok = np.zeros(k, dtype=np.bool_)
    d2 = np.full(k, np.inf)
    r = np.zeros((k, 2))
    Hc = np.zeros((k, 2, 6))
    He = np.zeros((k, 2, 6))
    Hf = np.zeros((k, 2, 3))
    ne = 6 if eidx >= 0 else 0
    nc = 9 + ne
    cols = np.empty(nc, dtype=np.int64)
    for j in range(6):
        cols[j] = cidx + j
    for j in range(ne):
        cols[6 + j] = eidx + j
    for i in range(k):
        good, rr, hc, he, hf = feature_jacobians(Rc, pc, Rf, pf, uv[i:i + 1], lp[i], lfej[i], R_IC, p_IC,
                                                 code, prm)
        if not good:
            continue
        for j in range(3):
            cols[6 + ne + j] = lidx[i] + j
        H = np.zeros((2, nc))
        H[:, 0:6] = hc
        if ne > 0:
            H[:, 6:12] = he
        H[:, 6 + ne:] = hf
        Pl = np.empty((nc, nc))
        for a in range(nc):
            for b in range(nc):
                Pl[a, b] = P[cols[a], cols[b]]
        S = H @ Pl @ H.T
        S[0, 0] += sigma * sigma
        S[1, 1] += sigma * sigma
        det = S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]
        if det <= 0:
            continue
        q = S[1, 1] * rr[0] * rr[0] - (S[0, 1] + S[1, 0]) * rr[0] * rr[1] + S[0, 0] * rr[1] * rr[1]
        d2[i] = q / det
        ok[i] = True
        r[i] = rr
        Hc[i] = hc
        He[i] = he
        Hf[i] = hf
    return ok, d2, r, Hc, He, Hf


def slam_update(state: State, t_cam_ns: int, obs: list[tuple[int, np.ndarray]], cfg: MsckfConfig,
                cam: CameraParams, stats: SlamUpdateStats) -> None:
    """Update with landmarks observed at clone t_cam_ns; obs = [(fid, uv (2,))], in batches."""
    if not obs or t_cam_ns not in state.clones:
        return
    c = state.clones[t_cam_ns]
    fej = cfg.use_fej
    batch = max(1, cfg.max_slam_in_update)
    gate = cfg.chi2_multiplier * chi2_95(2)
    for b0 in range(0, len(obs), batch):
        chunk = obs[b0:b0 + batch]
        lms = [state.slam[fid] for fid, _ in chunk]
        lidx = np.array([lm.idx for lm in lms], dtype=np.int64)
        uv = np.array([u for _, u in chunk])
        lp = np.array([lm.p for lm in lms])
        lf = np.array([lm.p_fej for lm in lms]) if fej else lp
        ok, d2, r, Hc, He, Hf = slam_rows(state.P, c.idx, state.idx_ext, lidx, c.R[None], c.p[None],
                                          c.R_fej[None], c.p_fej[None], uv, lp, lf, state.R_IC, state.p_IC,
                                          cam.code, cam.params, cfg.sigma_pix)
        good = ok & (d2 < gate)
        for lm, g in zip(lms, good, strict=True):
            if not g:
                lm.fail_count += 1
        stats.chi2_rejected += int((~good).sum())
        sel = np.flatnonzero(good)
        if sel.size == 0:
            continue
        stats.updated += int(sel.size)
        ne = 6 if state.idx_ext >= 0 else 0
        cols = list(range(c.idx, c.idx + 6))
        if ne:
            cols += list(range(state.idx_ext, state.idx_ext + 6))
        base = len(cols)
        for i in sel:
            cols += list(range(lidx[i], lidx[i] + 3))
        H = np.zeros((2 * sel.size, len(cols)))
        for k, i in enumerate(sel):
            H[2 * k:2 * k + 2, 0:6] = Hc[i]
            if ne:
                H[2 * k:2 * k + 2, 6:12] = He[i]
            H[2 * k:2 * k + 2, base + 3 * k:base + 3 * k + 3] = Hf[i]
        Hq, rq = compress(H, r[sel].reshape(-1))
        ekf_update(state, np.asarray(cols, dtype=np.int64), Hq, rq, cfg.sigma_pix)


def delayed_init(state: State, tracks: list[Track], cfg: MsckfConfig, cam: CameraParams,
                 stats: SlamUpdateStats) -> list[int]:
    """Initialise landmarks from tracks over the window; returns the ids that entered the state.

    Each landmark is created from the invertible part of its measurements; the remaining rows of all
    landmarks are applied in one stacked, compressed update at the end."""
    added = []
    if not tracks:
        return added
    cols, offset = window_columns(state)
    deferred: list = []
    for tr in tracks:
        cl, Rc, pc, Rf, pf, uv, xn = track_arrays(state, tr)
        if len(cl) < 2:
            stats.init_failed += 1
            continue
        ok, p_O = triangulate_track(state, cfg, Rc, pc, xn)
        if not ok:
            stats.init_failed += 1
            continue
        ok, r, Hc, He, Hf = feature_jacobians(Rc, pc, Rf, pf, uv, p_O, p_O, state.R_IC, state.p_IC,
                                              cam.code, cam.params)
        if not ok:
            stats.init_failed += 1
            continue
        Hx = np.zeros((r.shape[0], cols.size))
        if state.idx_ext >= 0:
            Hx[:, 0:6] = He
        for i, c in enumerate(cl):
            o = offset[c.t_cam_ns]
            Hx[2 * i:2 * i + 2, o:o + 6] = Hc[2 * i:2 * i + 2]
        if initialize_landmark(state, tr.fid, p_O, cols, Hx, Hf, r, cfg.sigma_pix, cfg.chi2_multiplier,
                               deferred):
            stats.initialized += 1
            added.append(tr.fid)
        else:
            stats.init_failed += 1
    if deferred:
        H, r = compress(np.vstack([h for h, _ in deferred]), np.concatenate([x for _, x in deferred]))
        ekf_update(state, cols, H, r, cfg.sigma_pix)
    return added
