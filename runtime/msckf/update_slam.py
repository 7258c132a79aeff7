"""SLAM landmarks: batched updates with the newest clone, delayed initialisation from long tracks
(OpenVINS UpdaterSLAM structure; global 3D or anchored inverse-depth landmarks, anchored in the newest
clone at initialisation)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from runtime.msckf.camera_kernels import CameraParams
from runtime.msckf.config import MsckfConfig
from runtime.msckf.feature_db import Track
from runtime.msckf.landmark_repr import anchored_to_global, global_to_anchored
from runtime.msckf.measurement import feature_intrinsics_jacobian, feature_jacobians
from runtime.msckf.state import Landmark, State
from runtime.msckf.state_helper import add_landmarks, chi2_95, compress, ekf_update, split_landmark_rows
from runtime.msckf.track_linearization import linearize_tracks, window_columns


@dataclass
class SlamUpdateStats:
    """Counts of the SLAM stage of one frame."""

    updated: int = 0
    chi2_rejected: int = 0
    initialized: int = 0
    init_failed: int = 0
    #: stacked EKF updates not applied (innovation covariance not positive definite); their observations are
    #: not counted in `updated`
    update_failed: int = 0


@njit(cache=True, nogil=True)
def _mul23(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """A B for a 2x3 A and a 3xk B (scalar loops: numba sends every small `@` to BLAS)."""
    out = np.empty((2, B.shape[1]))
    for i in range(2):
        for j in range(B.shape[1]):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]
    return out


@njit(cache=True, nogil=True)
def _project_cov2(P: np.ndarray, cols: np.ndarray, H: np.ndarray) -> np.ndarray:
    """H P[cols][:, cols] H^T (2x2) for a 2 x len(cols) H, without gathering the block."""
    nc = cols.shape[0]
    S = np.zeros((2, 2))
    for a in range(nc):
        row = cols[a]
        t0 = 0.0
        t1 = 0.0
        for b in range(nc):
            pab = P[row, cols[b]]
            t0 += pab * H[0, b]
            t1 += pab * H[1, b]
        S[0, 0] += H[0, a] * t0
        S[0, 1] += H[0, a] * t1
        S[1, 0] += H[1, a] * t0
        S[1, 1] += H[1, a] * t1
    return S


@njit(cache=True, nogil=True)
def slam_rows(P: np.ndarray, cidx: int, eidx: int, lidx: np.ndarray, aidx: np.ndarray, Rc: np.ndarray,
              pc: np.ndarray, Rf: np.ndarray, pf: np.ndarray, uv: np.ndarray, lp: np.ndarray,
              lfej: np.ndarray,
              RA: np.ndarray, pA: np.ndarray, RAf: np.ndarray, pAf: np.ndarray, R_IC: np.ndarray,
              p_IC: np.ndarray, code: int, prm: np.ndarray, sigma: float, kidx: int = -1) -> tuple:
    """Residuals, Jacobians and Mahalanobis distances of k landmarks seen by one clone.

    P: full covariance; cidx/eidx/kidx: clone, extrinsics and intrinsics columns (eidx, kidx < 0: not
    estimated); lidx (k,) landmark columns; aidx (k,) anchor-clone columns of anchored inverse-depth
    landmarks (-1: global 3D landmark), with the anchors' current (RA, pA) and first-estimate (RAf, pAf)
    poses.
    Returns ok (k,), d2 (k,), r (k,2), Hc (k,2,6), Ha (k,2,6) anchor, He (k,2,6), Hl (k,2,3),
    Hk (k,2,8) intrinsics (zero when not estimated).
    """
    k = lidx.shape[0]
    ok = np.zeros(k, dtype=np.bool_)
    d2 = np.full(k, np.inf)
    r = np.zeros((k, 2))
    Hc = np.zeros((k, 2, 6))
    Ha = np.zeros((k, 2, 6))
    He = np.zeros((k, 2, 6))
    Hl = np.zeros((k, 2, 3))
    Hk = np.zeros((k, 2, 8))
    ne = 6 if eidx >= 0 else 0
    nk = 8 if kidx >= 0 else 0
    for i in range(k):
        anchored = aidx[i] >= 0
        if anchored:
            # linearised at the current point re-expressed through the anchor's first estimate (OpenVINS
            # UpdaterHelper::get_feature_jacobian_representation): the landmark has no first estimate of its
            # own, only the anchor's pose is held at its first estimate
            p_O, _, _, _ = anchored_to_global(lp[i], RA[i], pA[i], R_IC, p_IC)
            lam_f, _, _, _ = global_to_anchored(p_O, RAf[i], pAf[i], R_IC, p_IC)
            p_Of, J_lam, J_anc, J_ext = anchored_to_global(lam_f, RAf[i], pAf[i], R_IC, p_IC)
        else:
            p_O = lp[i]
            p_Of = lfej[i]
        good, rr, hc, he, hf = feature_jacobians(Rc, pc, Rf, pf, uv[i:i + 1], p_O, p_Of, R_IC, p_IC, code,
                                                 prm)
        if not good:
            continue
        hk = np.zeros((2, 8))
        if nk > 0:
            hk = feature_intrinsics_jacobian(Rf, pf, p_Of, R_IC, p_IC, code, prm)
        ha = np.zeros((2, 6))
        sep = False
        if anchored:
            hl = _mul23(hf, J_lam)
            ha = _mul23(hf, J_anc)
            he = he + _mul23(hf, J_ext)
            if aidx[i] == cidx:
                hc = hc + ha
                ha = np.zeros((2, 6))
            else:
                sep = True
        else:
            hl = hf
        na = 6 if sep else 0
        nc = 6 + ne + nk + na + 3
        cols = np.empty(nc, dtype=np.int64)
        H = np.zeros((2, nc))
        for j in range(6):
            cols[j] = cidx + j
        H[:, 0:6] = hc
        for j in range(ne):
            cols[6 + j] = eidx + j
        if ne > 0:
            H[:, 6:12] = he
        for j in range(nk):
            cols[6 + ne + j] = kidx + j
        if nk > 0:
            H[:, 6 + ne:14 + ne] = hk
        for j in range(na):
            cols[6 + ne + nk + j] = aidx[i] + j
        if na > 0:
            H[:, 6 + ne + nk:12 + ne + nk] = ha
        for j in range(3):
            cols[6 + ne + nk + na + j] = lidx[i] + j
        H[:, 6 + ne + nk + na:] = hl
        S = _project_cov2(P, cols, H)
        S[0, 0] += sigma * sigma
        S[1, 1] += sigma * sigma
        det = S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]
        if det <= 0 or S[0, 0] <= 0:     # a 2x2 S is positive definite iff both hold
            continue
        q = S[1, 1] * rr[0] * rr[0] - (S[0, 1] + S[1, 0]) * rr[0] * rr[1] + S[0, 0] * rr[1] * rr[1]
        d2[i] = q / det
        ok[i] = True
        r[i] = rr
        Hc[i] = hc
        Ha[i] = ha
        He[i] = he
        Hl[i] = hl
        Hk[i] = hk
    return ok, d2, r, Hc, Ha, He, Hl, Hk


@njit(cache=True, nogil=True)
def assemble_slam_rows(sel: np.ndarray, cidx: int, eidx: int, kidx: int, aidx: np.ndarray, lidx: np.ndarray,
                       Hc: np.ndarray, He: np.ndarray, Hk: np.ndarray, Ha: np.ndarray, Hl: np.ndarray,
                       n: int) -> tuple[np.ndarray, np.ndarray]:
    """Stack the selected landmarks' row pairs (slam_rows' blocks) into one Jacobian over the columns it
    touches: the measuring clone, extrinsics and intrinsics (when estimated), then anchors and landmarks in
    order of appearance (an anchor that is the measuring clone adds to its block). n: state size.
    Returns (H (2 len(sel), ncols), cols (ncols,) state indices)."""
    ns = sel.shape[0]
    offset = np.full(n, -1, dtype=np.int64)
    cols = np.empty(6 + 6 + 8 + 9 * ns, dtype=np.int64)
    nc = 0
    for start, size in ((cidx, 6), (eidx, 6), (kidx, 8)):
        if start >= 0:
            offset[start] = nc
            for j in range(size):
                cols[nc + j] = start + j
            nc += size
    H = np.zeros((2 * ns, cols.shape[0]))
    for k in range(ns):
        i = sel[k]
        H[2 * k:2 * k + 2, 0:6] = Hc[i]
        if eidx >= 0:
            H[2 * k:2 * k + 2, 6:12] = He[i]
        if kidx >= 0:
            o = offset[kidx]
            H[2 * k:2 * k + 2, o:o + 8] = Hk[i]
        for b in range(2):
            start = aidx[i] if b == 0 else lidx[i]
            size = 6 if b == 0 else 3
            if b == 0 and (start < 0 or start == cidx):
                continue
            if offset[start] < 0:
                offset[start] = nc
                for j in range(size):
                    cols[nc + j] = start + j
                nc += size
            o = offset[start]
            if b == 0:
                H[2 * k:2 * k + 2, o:o + 6] += Ha[i]
            else:
                H[2 * k:2 * k + 2, o:o + 3] += Hl[i]
    return H[:, :nc].copy(), cols[:nc].copy()


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
        if all(lm.anchor_t is None for lm in lms):      # global 3D: no anchor (the kernel ignores these)
            k = len(lms)
            aidx = np.full(k, -1, dtype=np.int64)
            RA = np.tile(np.eye(3), (k, 1, 1))
            pA = np.zeros((k, 3))
            RAf, pAf = RA, pA
        else:
            anchors = [state.clones[lm.anchor_t] if lm.anchor_t is not None else None for lm in lms]
            aidx = np.array([a.idx if a is not None else -1 for a in anchors], dtype=np.int64)
            eye = np.eye(3)
            RA = np.array([a.R if a is not None else eye for a in anchors])
            pA = np.array([a.p if a is not None else np.zeros(3) for a in anchors])
            RAf = np.array([a.R_fej if a is not None else eye for a in anchors]) if fej else RA
            pAf = np.array([a.p_fej if a is not None else np.zeros(3) for a in anchors]) if fej else pA
        uv = np.array([u for _, u in chunk])
        lp = np.array([lm.p for lm in lms])
        lf = np.array([lm.p_fej for lm in lms]) if fej else lp
        ok, d2, r, Hc, Ha, He, Hl, Hk = slam_rows(
            state.P, c.idx, state.idx_ext, lidx, aidx, c.R[None], c.p[None],
            c.R_fej[None] if fej else c.R[None], c.p_fej[None] if fej else c.p[None], uv, lp, lf,
            RA, pA, RAf, pAf, state.R_IC, state.p_IC, cam.code, state.camera_params(cam.params),
            float(cfg.sigma_pix), state.idx_intr)
        good = ok & (d2 < gate)
        # a landmark that cannot be projected (behind the camera) is counted toward removal; a chi-square
        # rejection drops this observation and counts toward it unless cfg.slam_max_chi2_failures is None
        count_chi2 = cfg.slam_max_chi2_failures is not None
        for lm, projected, passed in zip(lms, ok, good, strict=True):
            if not projected:
                lm.fail_count += 1
            elif not passed and count_chi2:
                lm.chi2_failures += 1
        stats.chi2_rejected += int((ok & ~good).sum())  # a failed projection is not a chi-square rejection
        sel = np.flatnonzero(good)
        if sel.size == 0:
            continue
        H, cols = assemble_slam_rows(sel, c.idx, state.idx_ext, state.idx_intr, aidx, lidx, Hc, He, Hk, Ha,
                                     Hl, state.size)
        Hq, rq = compress(H, r[sel].reshape(-1))
        if ekf_update(state, cols, Hq, rq, cfg.sigma_pix):
            stats.updated += int(sel.size)
        else:
            stats.update_failed += 1


def delayed_init(state: State, tracks: list[Track], cfg: MsckfConfig, cam: CameraParams,
                 stats: SlamUpdateStats) -> list[int]:
    """Initialise landmarks from tracks over the window; returns the ids that entered the state.

    Each landmark is created from the invertible part of its measurements; the remaining rows of all
    landmarks are applied in one stacked, compressed update at the end."""
    added = []
    if not tracks:
        return added
    cols, offset = window_columns(state)
    # the window's covariance block: new landmarks append rows and columns, and the deferred rows are applied
    # after the loop, so it holds for every track
    Pcc = state.P[np.ix_(cols, cols)]
    deferred: list = []
    accepted: list = []
    anchored = cfg.slam_representation == "anchored_inverse_depth"
    anchor = state.clones[state.clone_times()[-1]] if anchored else None
    for tr, lin in zip(tracks, linearize_tracks(state, tracks, cfg, cam), strict=True):
        if lin is None:
            stats.init_failed += 1
            continue
        p_O, p_lin, r, Hx, Hf = lin
        value, H_lm, fej = p_O, Hf, p_lin
        if anchor is not None:
            # lam in the newest clone's camera; its first estimate maps back to p_lin through the anchor's
            # first estimate, so the pixel Jacobians of `lin` hold and only the chain rule is added
            value, _, _, _ = global_to_anchored(p_O, anchor.R, anchor.p, state.R_IC, state.p_IC)
            fej, _, _, _ = global_to_anchored(p_lin, anchor.R_fej, anchor.p_fej, state.R_IC, state.p_IC)
            _, J_lam, J_anc, J_ext = anchored_to_global(fej, anchor.R_fej, anchor.p_fej, state.R_IC,
                                                        state.p_IC)
            if state.idx_ext >= 0:
                Hx[:, 0:6] += Hf @ J_ext
            o = offset[anchor.t_cam_ns]
            Hx[:, o:o + 6] += Hf @ J_anc
            H_lm = Hf @ J_lam
        split = split_landmark_rows(Pcc, Hx, H_lm, r, cfg.sigma_pix, cfg.chi2_multiplier)
        if split is None:
            stats.init_failed += 1
            continue
        Hf1_inv, Hx1, r1, Hx2, r2 = split
        accepted.append((tr.fid, value, fej, Hf1_inv, Hx1, r1))
        if Hx2.shape[0] > 0:
            deferred.append((Hx2, r2))
    # every gate above used the window's covariance before any landmark entered: one covariance copy for all
    for lm in add_landmarks(state, cols, accepted, cfg.sigma_pix):
        if anchor is not None:
            lm.anchor_t = anchor.t_cam_ns
        stats.initialized += 1
        added.append(lm.fid)
    if deferred:
        H, r = compress(np.vstack([h for h, _ in deferred]), np.concatenate([x for _, x in deferred]))
        if not ekf_update(state, cols, H, r, cfg.sigma_pix):
            stats.update_failed += 1   # the landmarks keep their invertible part; the rest is not applied
    return added


def change_anchor(state: State, lm: Landmark, new_t: int) -> None:
    """Re-express an anchored inverse-depth landmark in the clone at new_t (value, FEJ and covariance).

    Before its anchor clone is marginalised (OpenVINS UpdaterSLAM::change_anchors). The new parameters are a
    function of (old lam, old anchor, new anchor, extrinsics); the covariance rows of lam are replaced by the
    linearisation of that function at the current point, the anchors held at their first estimates
    (`anchor_change_kernel`).
    """
    old = state.clones[lm.anchor_t]
    new = state.clones[new_t]
    if new is old:
        return
    if not state.P.flags.c_contiguous:
        state.P = np.ascontiguousarray(state.P)
    lam_new, lam_new_fej = anchor_change_kernel(
        state.P, lm.p, lm.p_fej, old.R, old.p, old.R_fej, old.p_fej, old.idx, new.R, new.p, new.R_fej,
        new.p_fej, new.idx, state.R_IC, state.p_IC, lm.idx, state.idx_ext)
    lm.p = lam_new
    lm.p_fej = lam_new_fej
    lm.anchor_t = new_t


@njit(cache=True, nogil=True)
def anchor_change_kernel(P: np.ndarray, lam: np.ndarray, lam_fej: np.ndarray, R_o: np.ndarray,
                         p_o: np.ndarray, Rf_o: np.ndarray, pf_o: np.ndarray, oidx: int, R_n: np.ndarray,
                         p_n: np.ndarray, Rf_n: np.ndarray, pf_n: np.ndarray, nidx: int, R_IC: np.ndarray,
                         p_IC: np.ndarray, lidx: int, eidx: int) -> tuple[np.ndarray, np.ndarray]:
    """`change_anchor`'s numbers: the landmark lam (its FEJ lam_fej) anchored in the old clone (pose R_o,
    p_o, first estimate Rf_o, pf_o, covariance column oidx) re-expressed in the new clone (nidx); the
    covariance rows and columns of the landmark (lidx) are replaced in P (in place) by J P[cols] with J the
    Jacobian of the new lam w.r.t. (lam, old anchor, new anchor, extrinsics at eidx >= 0), evaluated at the
    current point through the anchors' first estimates (OpenVINS perform_anchor_change).
    Returns (lam in the new anchor, its first estimate)."""
    p_O = anchored_to_global(lam, R_o, p_o, R_IC, p_IC)[0]
    lam_new = global_to_anchored(p_O, R_n, p_n, R_IC, p_IC)[0]
    lam_old_fej = global_to_anchored(p_O, Rf_o, pf_o, R_IC, p_IC)[0]
    if not (lam_old_fej[2] > 0 and np.isfinite(lam_old_fej[0]) and np.isfinite(lam_old_fej[1])
            and np.isfinite(lam_old_fej[2])):   # behind the first-estimate anchor
        lam_old_fej = lam_fej.copy()
    p_Of, Jl_o, Ja_o, Je_o = anchored_to_global(lam_old_fej, Rf_o, pf_o, R_IC, p_IC)
    lam_new_fej, Jp_n, Ja_n, Je_n = global_to_anchored(p_Of, Rf_n, pf_n, R_IC, p_IC)
    # J over [lam (3), old anchor (6), new anchor (6), extrinsics (6, when estimated)]
    nj = 15 if eidx < 0 else 21
    J = np.zeros((3, nj))
    cols = np.empty(nj, dtype=np.int64)
    for a in range(3):
        for k in range(3):
            J[a, k] = Jp_n[a, 0] * Jl_o[0, k] + Jp_n[a, 1] * Jl_o[1, k] + Jp_n[a, 2] * Jl_o[2, k]
        for k in range(6):
            J[a, 3 + k] = Jp_n[a, 0] * Ja_o[0, k] + Jp_n[a, 1] * Ja_o[1, k] + Jp_n[a, 2] * Ja_o[2, k]
            J[a, 9 + k] = Ja_n[a, k]
            if eidx >= 0:
                J[a, 15 + k] = (Jp_n[a, 0] * Je_o[0, k] + Jp_n[a, 1] * Je_o[1, k] + Jp_n[a, 2] * Je_o[2, k]
                                + Je_n[a, k])
    for k in range(3):
        cols[k] = lidx + k
    for k in range(6):
        cols[3 + k] = oidx + k
        cols[9 + k] = nidx + k
        if eidx >= 0:
            cols[15 + k] = eidx + k
    n = P.shape[0]
    row = np.zeros((3, n))          # J P[cols, :]
    for k in range(nj):
        c = cols[k]
        for a in range(3):
            jak = J[a, k]
            for j in range(n):
                row[a, j] += jak * P[c, j]
    corner = np.zeros((3, 3))       # J P[cols][:, cols] J^T
    for a in range(3):
        for b in range(3):
            acc = 0.0
            for k in range(nj):
                acc += row[a, cols[k]] * J[b, k]
            corner[a, b] = acc
    for a in range(3):
        for j in range(n):
            P[lidx + a, j] = row[a, j]
            P[j, lidx + a] = row[a, j]
    for a in range(3):
        for b in range(3):
            P[lidx + a, lidx + b] = 0.5 * (corner[a, b] + corner[b, a])
    return lam_new, lam_new_fej
