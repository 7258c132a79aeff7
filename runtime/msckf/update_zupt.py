"""Zero-velocity update (OpenVINS UpdaterZeroVelocity's decision rule, own residual): the body is taken
to stand still when the features barely moved (mean disparity below zupt_max_disparity over more than
MIN_DISPARITY_FEATURES features; disabled at 0), or else when the IMU samples since the last frame are
consistent with standstill (chi-square on w = bg, a = ba + R^T g_up within zupt_chi2_multiplier times
the 95 % quantile; a multiplier of 0 leaves the disparity test alone) and the speed estimate is below
zupt_max_velocity. It then updates with those IMU residuals plus v = 0 (the velocity row is ours: OpenVINS
instead does not propagate while still) and adds no clone.

Unlike OpenVINS, which compares with the previous frame, the disparity is measured against each
feature's newest stored observation at least zupt_disparity_span_s older than this frame: slow motion
(a few px per second) accumulates disparity over that span instead of passing a frame-to-frame test
and being held at zero velocity.
"""
from __future__ import annotations

from bisect import bisect_right

import numpy as np

from runtime.msckf.config import MsckfConfig
from runtime.msckf.feature_db import FeatureDatabase
from runtime.msckf.measurement import projected_mahalanobis
from runtime.msckf.so3_kernels import skew3
from runtime.msckf.state import State
from runtime.msckf.state_helper import chi2_accepts, compress, ekf_update

MIN_DISPARITY_FEATURES = 20
"""The disparity test needs more features than this (OpenVINS: 20)."""


def mean_disparity(db: FeatureDatabase, t_cam_ns: int, ids: np.ndarray, uv: np.ndarray,
                   span_ns: int = 0) -> tuple[float, int]:
    """Mean pixel distance between this frame's features (camera time t_cam_ns) and, per feature, its
    newest stored observation at least span_ns older; and the number of features averaged (inf, 0 when
    none has such an observation)."""
    tracks = db.tracks
    t_max = t_cam_ns - span_ns
    rows, past = [], []
    for k, fid in enumerate(ids.tolist()):
        tr = tracks.get(fid)
        if tr is None:
            continue
        j = bisect_right(tr.t_ns, t_max) - 1     # the track's times increase
        if j >= 0:
            rows.append(k)
            past.append(tr.uv[j])
    if not rows:
        return float("inf"), 0
    d = np.linalg.norm(np.asarray(uv, dtype=np.float64)[rows] - np.asarray(past, dtype=np.float64), axis=1)
    return float(d.mean()), len(rows)


def disparity_says_static(cfg: MsckfConfig, db: FeatureDatabase, t_cam_ns: int, ids: np.ndarray,
                          uv: np.ndarray) -> bool:
    """True when the disparity test is enabled and the features barely moved over the span."""
    if not cfg.zupt_max_disparity > 0:
        return False
    span_ns = int(round(cfg.zupt_disparity_span_s * 1e9))
    disp, n = mean_disparity(db, t_cam_ns, ids, uv, span_ns)
    return disp < cfg.zupt_max_disparity and n > MIN_DISPARITY_FEATURES


def zupt_update(st: State, cfg: MsckfConfig, db: FeatureDatabase, samples: tuple | None, t_cam_ns: int,
                ids: np.ndarray, uv: np.ndarray) -> bool:
    """Try a zero-velocity update with the IMU samples (t (n,) s, w (n,3), a (n,3)) of the last propagation
    interval and this frame's features (camera time t_cam_ns, ids, uv); True when applied."""
    if samples is None or not st.clones:
        return False
    t, ws, as_ = samples
    if t.shape[0] < 2:
        return False
    still = disparity_says_static(cfg, db, t_cam_ns, ids, uv)
    if not still and (cfg.zupt_chi2_multiplier <= 0 or float(np.linalg.norm(st.v)) > cfg.zupt_max_velocity):
        return False
    n = t.shape[0]
    dt = max(float(t[-1] - t[0]) / max(n - 1, 1), 1e-4)
    g_up = np.array([0.0, 0.0, cfg.gravity_mag])
    f = st.R.T @ g_up
    m = 6 * n + 3
    H = np.zeros((m, 15))
    r = np.zeros(m)
    sig = np.zeros(m)
    mult = np.sqrt(cfg.zupt_noise_multiplier)   # a variance multiplier, as OpenVINS's R = mult * I
    for k in range(n):
        o = 6 * k
        r[o:o + 3] = ws[k] - st.bg
        H[o:o + 3, 9:12] = np.eye(3)
        sig[o:o + 3] = mult * cfg.gyro_noise_density / np.sqrt(dt)
        r[o + 3:o + 6] = as_[k] - st.ba - f
        H[o + 3:o + 6, 0:3] = skew3(f)
        H[o + 3:o + 6, 12:15] = np.eye(3)
        sig[o + 3:o + 6] = mult * cfg.accel_noise_density / np.sqrt(dt)
    r[6 * n:] = -st.v
    H[6 * n:, 6:9] = np.eye(3)
    sig[6 * n:] = mult * cfg.accel_noise_density / np.sqrt(dt) * dt
    # whiten so that the EKF update sees unit isotropic noise
    Hw = H / sig[:, None]
    rw = r / sig
    cols = np.arange(15)
    if not still:
        d2 = projected_mahalanobis(np.ascontiguousarray(st.P[:15, :15]), np.ascontiguousarray(Hw[: 6 * n]),
                                   np.ascontiguousarray(rw[: 6 * n]), 1.0)
        if not chi2_accepts(d2, 6 * n, cfg.zupt_chi2_multiplier):
            return False
    Hc, rc = compress(Hw, rw)
    return ekf_update(st, cols, Hc, rc, 1.0)
