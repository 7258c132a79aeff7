"""MSCKF feature update: triangulate, linearise in distorted pixels, project out the feature
(nullspace), chi-square gate, stack, QR-compress, one EKF update (OpenVINS UpdaterMSCKF structure)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from runtime.msckf.camera_kernels import CameraParams
from runtime.msckf.config import MsckfConfig
from runtime.msckf.feature_db import Track
from runtime.msckf.state import State
from runtime.msckf.state_helper import compress, ekf_update
from runtime.msckf.track_linearization import CHI2_REJECTED, NOT_LINEARIZED, OK, msckf_rows, window_columns


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
    cols, _ = window_columns(state)
    status, H, r = msckf_rows(state, tracks, cfg, cam, state.P[np.ix_(cols, cols)])
    st.triangulation_failed = int(np.count_nonzero(status == NOT_LINEARIZED))
    st.chi2_rejected = int(np.count_nonzero(status == CHI2_REJECTED))
    used = int(np.count_nonzero(status == OK))
    if used == 0:
        return st
    H, r = compress(H, r)
    if not ekf_update(state, cols, H, r, cfg.sigma_pix):
        st.update_failed = 1   # the state is unchanged: no track informed it
        return st
    st.used = used
    st.rows = H.shape[0]
    return st
