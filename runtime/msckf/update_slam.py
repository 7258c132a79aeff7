"""SLAM landmarks: batched updates with the newest clone, delayed initialisation from long tracks
(OpenVINS UpdaterSLAM structure; global 3D landmarks)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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


def slam_update(state: State, t_cam_ns: int, obs: list[tuple[int, np.ndarray]], cfg: MsckfConfig,
                cam: CameraParams, stats: SlamUpdateStats) -> None:
    """Update with landmarks observed at clone t_cam_ns; obs = [(fid, uv (2,))], in batches."""
    if not obs or t_cam_ns not in state.clones:
        return
    c = state.clones[t_cam_ns]
    fej = cfg.use_fej
    batch = max(1, cfg.max_slam_in_update)
    for b0 in range(0, len(obs), batch):
        chunk = obs[b0:b0 + batch]
        cols = list(range(c.idx, c.idx + 6))
        if state.idx_ext >= 0:
            cols += list(range(state.idx_ext, state.idx_ext + 6))
        base = len(cols)
        for fid, _ in chunk:
            lm = state.slam[fid]
            cols += list(range(lm.idx, lm.idx + 3))
        cols_a = np.asarray(cols, dtype=np.int64)
        Pcc = state.P[np.ix_(cols_a, cols_a)]
        Hs, rs = [], []
        for k, (fid, uv) in enumerate(chunk):
            lm = state.slam[fid]
            ok, r, Hc, He, Hf = feature_jacobians(c.R[None], c.p[None], c.R_fej[None], c.p_fej[None],
                                                  uv[None], lm.p, lm.p_fej if fej else lm.p,
                                                  state.R_IC, state.p_IC, cam.code, cam.params)
            if not ok:
                lm.fail_count += 1
                stats.chi2_rejected += 1
                continue
            H = np.zeros((2, cols_a.size))
            H[:, 0:6] = Hc
            if state.idx_ext >= 0:
                H[:, 6:12] = He
            o = base + 3 * k
            H[:, o:o + 3] = Hf
            S = H @ Pcc @ H.T + cfg.sigma_pix ** 2 * np.eye(2)
            d2 = float(r @ np.linalg.solve(S, r))
            if not d2 < cfg.chi2_multiplier * chi2_95(2):
                lm.fail_count += 1
                stats.chi2_rejected += 1
                continue
            Hs.append(H)
            rs.append(r)
            stats.updated += 1
        if Hs:
            H, r = compress(np.vstack(Hs), np.concatenate(rs))
            ekf_update(state, cols_a, H, r, cfg.sigma_pix)


def delayed_init(state: State, tracks: list[Track], cfg: MsckfConfig, cam: CameraParams,
                 stats: SlamUpdateStats) -> list[int]:
    """Initialise landmarks from tracks over the window; returns the ids that entered the state."""
    added = []
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
        cols, offset = window_columns(state)
        Hx = np.zeros((r.shape[0], cols.size))
        if state.idx_ext >= 0:
            Hx[:, 0:6] = He
        for i, c in enumerate(cl):
            o = offset[c.t_cam_ns]
            Hx[2 * i:2 * i + 2, o:o + 6] = Hc[2 * i:2 * i + 2]
        if initialize_landmark(state, tr.fid, p_O, cols, Hx, Hf, r, cfg.sigma_pix, cfg.chi2_multiplier):
            stats.initialized += 1
            added.append(tr.fid)
        else:
            stats.init_failed += 1
    return added
