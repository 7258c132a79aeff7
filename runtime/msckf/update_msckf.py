"""MSCKF feature update: triangulate, linearise in distorted pixels, project out the feature
(nullspace), chi-square gate, stack, QR-compress, one EKF update (OpenVINS UpdaterMSCKF structure)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from runtime.msckf.camera_kernels import CameraParams
from runtime.msckf.config import MsckfConfig
from runtime.msckf.feature_db import Track
from runtime.msckf.measurement import givens_left_nullspace
from runtime.msckf.state import State
from runtime.msckf.state_helper import chi2_accepts, compress, ekf_update, innovation_mahalanobis
from runtime.msckf.track_linearization import linearize_track, window_columns


@dataclass
class MsckfUpdateStats:
    """Counts of one MSCKF update."""

    candidates: int = 0
    triangulation_failed: int = 0
    chi2_rejected: int = 0
    used: int = 0
    rows: int = 0
    #: 1 when the stacked update was not applied (innovation covariance not positive definite): nothing used
    update_failed: int = 0


def msckf_update(state: State, tracks: list[Track], cfg: MsckfConfig, cam: CameraParams) -> MsckfUpdateStats:
    """Use `tracks` (each with >= 2 observations at clones) in one MSCKF update."""
    st = MsckfUpdateStats(candidates=len(tracks))
    if not tracks:
        return st
    cols, offset = window_columns(state)
    ncol = cols.size
    Pcc = state.P[np.ix_(cols, cols)]
    Hs: list[np.ndarray] = []
    rs: list[np.ndarray] = []
    for tr in tracks:
        lin = linearize_track(state, tr, cfg, cam, ncol, offset)
        if lin is None:
            st.triangulation_failed += 1
            continue
        Hx2, r2, _, _, _ = givens_left_nullspace(lin.Hf, lin.Hx, lin.r)
        if Hx2.shape[0] == 0:
            continue
        d2 = innovation_mahalanobis(Pcc, Hx2, r2, cfg.sigma_pix)
        if not chi2_accepts(d2, r2.shape[0], cfg.chi2_multiplier):
            st.chi2_rejected += 1
            continue
        Hs.append(Hx2)
        rs.append(r2)
        st.used += 1
    if not Hs:
        return st
    H = np.vstack(Hs)
    r = np.concatenate(rs)
    H, r = compress(H, r)
    if not ekf_update(state, cols, H, r, cfg.sigma_pix):
        st.update_failed, st.used = 1, 0   # the state is unchanged: no track informed it
        return st
    st.rows = H.shape[0]
    return st
