"""Load the filter's numba kernels before the first frame.

numba loads a cached kernel (or compiles it) at its first call. Left to the first frames, that stalls the
frame after initialisation by about 0.2 s and the first update by another 0.06 s on a 2-core machine: the
first poses of a live run come late. `warm_kernels` runs the filter's update steps once on a small synthetic
window (a straight camera path past a wall of points, exact pixels) with the estimator's configuration, so
that every kernel of the per-frame path is loaded when the estimator is built. Once per process and
configuration shape: the loaded kernels stay for the process.
"""
from __future__ import annotations

import time

import numpy as np

from runtime.msckf.camera_kernels import CameraParams, distort_points, undistort_points
from runtime.msckf.config import MsckfConfig
from runtime.msckf.feature_db import Track
from runtime.msckf.propagator import propagate_interval, select_samples
from runtime.msckf.state import State
from runtime.msckf.state_helper import augment_clone, marginalize
from runtime.msckf.update_msckf import msckf_update
from runtime.msckf.update_slam import SlamUpdateStats, change_anchor, delayed_init, slam_update

_WARMED: set[tuple] = set()


def warm_kernels(cfg: MsckfConfig, camera: CameraParams, R_IC: np.ndarray, p_IC: np.ndarray) -> float:
    """Run propagation, clone augmentation, the MSCKF update, delayed landmark initialisation, the SLAM
    update, an anchor change and marginalisation once on a synthetic window shaped like the estimator's
    state (calibration blocks as `cfg` asks). Returns the seconds it took (0 when this process already did
    it for this shape)."""
    key = (cfg.calib_time_offset, cfg.calib_extrinsics, cfg.calib_intrinsics, cfg.slam_representation,
           cfg.use_fej, camera.model)
    if key in _WARMED:
        return 0.0
    t0 = time.perf_counter()
    st = State(R_IC, p_IC, 0.0, cfg.calib_time_offset, cfg.calib_extrinsics,
               camera.params.copy() if cfg.calib_intrinsics else None)
    st.P = np.eye(st.size) * 1e-4
    # a camera moving sideways at 1 m/s past points 4-8 m ahead of it, observed exactly
    d = R_IC[:, 2]                                        # the camera's optical axis in the body frame
    side = np.cross(d, [0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.cross(d, [1.0, 0.0, 0.0])
    side /= np.linalg.norm(side)
    n_clones = 6
    times = [100_000_000 * (k + 1) for k in range(n_clones)]
    rng = np.random.default_rng(0)
    points = (rng.uniform(4.0, 8.0, (24, 1)) * d + rng.uniform(-1.5, 1.5, (24, 1)) * side
              + rng.uniform(-0.5, 0.5, (24, 1)) * np.cross(d, side))
    g = np.array([0.0, 0.0, -cfg.gravity_mag])
    for k, t in enumerate(times):
        st.p = side * 0.1 * k
        st.v = side.copy()
        augment_clone(st, t, np.zeros(3))
    tracks = []
    for j, p_O in enumerate(points):
        tr = Track(j + 1)
        for t in times:
            c = st.clones[t]
            pC = R_IC.T @ (c.R.T @ (p_O - c.p) - p_IC)
            uv = distort_points(camera.code, camera.params, (pC[:2] / pC[2])[None])
            tr.t_ns.append(t)
            tr.uv.append(uv[0].tolist())
            tr.xn.append(undistort_points(camera.code, camera.params, uv)[0].tolist())
        tracks.append(tr)
    loose = cfg.updated(chi2_multiplier=1e6)
    msckf_update(st, tracks[:12], loose, camera)
    stats = SlamUpdateStats()
    added = delayed_init(st, tracks[12:], loose, camera, stats)
    obs = [(tr.fid, np.asarray(tr.uv[-1])) for tr in tracks[12:] if tr.fid in added]
    slam_update(st, times[-1], obs, loose, camera, stats)
    for fid in added[1:2]:     # an anchored landmark moves to another clone (before its anchor leaves)
        if st.slam[fid].anchor_t is not None:
            change_anchor(st, st.slam[fid], times[-2])
    marginalize(st, [times[0]], added[:1])
    # propagation over a few IMU samples (sample selection included)
    t_imu = np.arange(6, dtype=np.int64) * 2_500_000 + times[-1]
    w = np.zeros((6, 3))
    a = np.tile(-g, (6, 1))
    ts, ws, as_ = select_samples(t_imu, w, a, int(t_imu[0]), int(t_imu[-1]))
    propagate_interval(st.R, st.p, st.v, st.bg, st.ba, st.R_fej, st.p_fej, st.v_fej, cfg.use_fej, ts, ws, as_,
                       g, cfg.gyro_noise_density, cfg.accel_noise_density, cfg.gyro_random_walk,
                       cfg.accel_random_walk)
    _WARMED.add(key)
    return time.perf_counter() - t0
