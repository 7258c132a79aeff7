"""One feature track linearised at the filter's clone window: its observations at the clones, triangulation,
the linearisation point and the stacked pixel Jacobians in the window's column layout. Shared by the MSCKF
update and the SLAM delayed initialisation."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from runtime.msckf.camera_kernels import CameraParams, undistort_points
from runtime.msckf.config import MsckfConfig
from runtime.msckf.feature_db import Track
from runtime.msckf.measurement import feature_intrinsics_jacobian, feature_jacobians
from runtime.msckf.state import State
from runtime.msckf.triangulation import triangulate


def track_arrays(state: State, tr: Track, cam: CameraParams) -> tuple:
    """Clone poses (current and FEJ) and measurements of a track's observations at existing clones.

    With online intrinsics the normalised coordinates xn are recomputed from the pixels with the state's
    current intrinsics through `cam`'s model (the database's were undistorted with older ones)."""
    ts = [t for t in tr.t_ns if t in state.clones]
    sel = [k for k, t in enumerate(tr.t_ns) if t in state.clones]
    cl = [state.clones[t] for t in ts]
    Rc = np.array([c.R for c in cl])
    pc = np.array([c.p for c in cl])
    Rf = np.array([c.R_fej for c in cl])
    pf = np.array([c.p_fej for c in cl])
    uv = np.array([tr.uv[k] for k in sel])
    if state.cam_params is not None:
        xn = undistort_points(cam.code, state.cam_params, uv)
    else:
        xn = np.array([tr.xn[k] for k in sel])
    return cl, Rc, pc, Rf, pf, uv, xn


def triangulate_track(state: State, cfg: MsckfConfig, Rc: np.ndarray, pc: np.ndarray, xn: np.ndarray
                      ) -> tuple[bool, np.ndarray]:
    """Triangulate with the current clone and extrinsic estimates."""
    R_OC = Rc @ state.R_IC
    p_OC = pc + Rc @ state.p_IC
    return triangulate(R_OC, p_OC, xn, cfg.tri_max_cond, cfg.tri_min_dist, cfg.tri_max_dist,
                       cfg.tri_max_baseline_ratio, cfg.tri_gn_iterations)


def linearization_point(state: State, cfg: MsckfConfig, Rf: np.ndarray, pf: np.ndarray, xn: np.ndarray,
                        p_O: np.ndarray) -> np.ndarray:
    """The feature position at which the Jacobians are evaluated: with FEJ and cfg.fej_triangulation, the
    point triangulated from the clones' first estimates, so that the linearisation is one consistent set of
    first estimates (p_O, from the current estimates, when that fails or FEJ is off)."""
    if not (cfg.use_fej and cfg.fej_triangulation):
        return p_O
    ok, p_f = triangulate_track(state, cfg, Rf, pf, xn)
    return p_f if ok else p_O


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


@dataclass
class TrackLinearization:
    """A track triangulated and linearised at the window's clones.

    clones, Rc, pc, Rf, pf, uv, xn: as track_arrays; p_O: triangulated point (odometry frame);
    p_lin: its linearisation point; r (2M,): pixel residuals; Hx (2M, ncol): Jacobian w.r.t. the
    window columns (extrinsics, intrinsics, clones); Hf (2M, 3): w.r.t. the point.
    """

    clones: list
    Rc: np.ndarray
    pc: np.ndarray
    Rf: np.ndarray
    pf: np.ndarray
    uv: np.ndarray
    p_O: np.ndarray
    p_lin: np.ndarray
    r: np.ndarray
    Hx: np.ndarray
    Hf: np.ndarray


def fill_window_columns(Hx: np.ndarray, He: np.ndarray, Hc: np.ndarray, clones: list, offset: dict,
                        has_extrinsics: bool, Hk: np.ndarray | None = None) -> None:
    """Write the extrinsics block He, the intrinsics block Hk (None: not estimated) and each observation's
    clone block of Hc into Hx (in place), in the window_columns layout."""
    if has_extrinsics:
        Hx[:, 0:6] = He
    if Hk is not None:
        o = 6 if has_extrinsics else 0
        Hx[:, o:o + 8] = Hk
    for i, c in enumerate(clones):
        o = offset[c.t_cam_ns]
        Hx[2 * i:2 * i + 2, o:o + 6] = Hc[2 * i:2 * i + 2]


def linearize_track(state: State, tr: Track, cfg: MsckfConfig, cam: CameraParams, ncol: int,
                    offset: dict) -> TrackLinearization | None:
    """Triangulate `tr` and build its residuals and Jacobians; None when it cannot be used."""
    cl, Rc, pc, Rf, pf, uv, xn = track_arrays(state, tr, cam)
    if len(cl) < 2:
        return None
    ok, p_O = triangulate_track(state, cfg, Rc, pc, xn)
    if not ok:
        return None
    p_lin = linearization_point(state, cfg, Rf, pf, xn, p_O)
    prm = state.camera_params(cam.params)
    ok, r, Hc, He, Hf = feature_jacobians(Rc, pc, Rf, pf, uv, p_O, p_lin, state.R_IC, state.p_IC,
                                          cam.code, prm)
    if not ok:
        return None
    Hk = None
    if state.idx_intr >= 0:
        Hk = feature_intrinsics_jacobian(Rf, pf, p_lin, state.R_IC, state.p_IC, cam.code, prm)
    Hx = np.zeros((r.shape[0], ncol))
    fill_window_columns(Hx, He, Hc, cl, offset, state.idx_ext >= 0, Hk)
    return TrackLinearization(cl, Rc, pc, Rf, pf, uv, p_O, p_lin, r, Hx, Hf)
