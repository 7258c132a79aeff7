"""The filter's state written from outside (an initializer's or a feed-forward start-up's estimate): the
IMU state with its covariance floored at the configured initial sigmas, and the priors of the online
calibration (extrinsics, time offset, intrinsics)."""
from __future__ import annotations

import numpy as np

from runtime.errors import EstimatorError
from runtime.msckf.camera_kernels import CameraParams
from runtime.msckf.config import MsckfConfig
from runtime.msckf.state import State

_NAMES = ("R_OI", "p_OI", "v_OI", "bg", "ba")
_SHAPES = ((3, 3), (3,), (3,), (3,), (3,))


def initial_state(cfg: MsckfConfig, camera: CameraParams, R_IC: np.ndarray, p_IC: np.ndarray, t_d: float,
                  t_ns: int, imu_state: tuple, cov: np.ndarray | None) -> State:
    """A new State at IMU time t_ns (ns) from `imu_state` = (R_OI, p_OI, v_OI, bg, ba) (odometry frame O,
    SI units), with the calibration prior (R_IC, p_IC, t_d: t_imu = t_cam + t_d, s).

    cov (15, 15) in the order [dtheta (body), dp, dv, dbg, dba], symmetrised, its diagonal floored at the
    config's init sigmas by scaling rows and columns (correlations kept); None: those sigmas. Raises
    EstimatorError naming the input that is not finite, of the wrong shape, or not a rotation."""
    vals = [np.asarray(x, dtype=float) for x in imu_state]
    for x, shape, name in zip(vals, _SHAPES, _NAMES, strict=True):
        if x.shape != shape or not np.all(np.isfinite(x)):
            raise EstimatorError(f"initialize_from_state: {name} must be finite with shape {shape}")
    R = vals[0]
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
        raise EstimatorError("initialize_from_state: R_OI is not a rotation")
    floor = np.repeat([cfg.init_sigma_ori, cfg.init_sigma_pos, cfg.init_sigma_vel, cfg.init_sigma_bg,
                       cfg.init_sigma_ba], 3) ** 2
    if cov is None:
        P = np.diag(floor)
    else:
        P = np.asarray(cov, dtype=float)
        if P.shape != (15, 15) or not np.all(np.isfinite(P)):
            raise EstimatorError("initialize_from_state: cov must be a finite (15, 15) matrix")
        P = 0.5 * (P + P.T)
        d = np.diag(P).copy()
        scale = np.sqrt(np.maximum(floor, d) / np.maximum(d, 1e-300))
        P = P * np.outer(scale, scale)
    st = State(R_IC, p_IC, t_d, cfg.calib_time_offset, cfg.calib_extrinsics,
               camera.params.copy() if cfg.calib_intrinsics else None)
    st.t_ns = int(t_ns)
    st.R, st.p, st.v, st.bg, st.ba = (x.copy() for x in vals)
    st.R_fej, st.p_fej, st.v_fej = st.R.copy(), st.p.copy(), st.v.copy()
    st.P[:15, :15] = P
    if st.idx_dt >= 0:
        st.P[st.idx_dt, st.idx_dt] = cfg.sigma_calib_dt**2
    if st.idx_ext >= 0:
        i = st.idx_ext
        st.P[i : i + 3, i : i + 3] = np.eye(3) * cfg.sigma_calib_rot**2
        st.P[i + 3 : i + 6, i + 3 : i + 6] = np.eye(3) * cfg.sigma_calib_pos**2
    if st.idx_intr >= 0:
        i = st.idx_intr
        sig = [cfg.sigma_calib_focal] * 2 + [cfg.sigma_calib_center] * 2
        # a camera without a distortion model has nothing that observes d0..d3 (zero Jacobian columns):
        # report them with zero uncertainty rather than an unchanging prior
        sig += [0.0 if camera.model == "none" else cfg.sigma_calib_distortion] * 4
        st.P[i : i + 8, i : i + 8] = np.diag(np.square(sig))
    return st
