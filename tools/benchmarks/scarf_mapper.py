"""A ScaRF-SLAM-style mapper on DAVIO's windows: the baseline of `davio bench mapping`.

It follows the released ScaRF-SLAM mapper as notes/scarf.md describes it, on the same keyframe
windows, poses and (emulated) DA3 call as DAVIO:
  * the pose-conditioned DA3 call with the window's poses (as ScaRF feeds T_WC and K to DA3);
  * ONE similarity per window, fitted from the model's returned cameras to the input (VIO) ones
    (least-squares on the centres as Umeyama, with the rotation taken from the camera orientations
    so that straight, collinear windows stay determined; `window_similarity`) and applied to the
    whole window: the depth AND the model's camera poses, so the placed baselines are the model's,
    scaled (DAVIO instead scales depth only and keeps the metric VIO baselines,
    runtime/mapping/placement.py). With DA3's `align_to_input_ext_scale`
    (and the emulated DA3) the conditioned call already returns the input poses with the depth
    divided by its own fit scale, so this similarity is then the identity up to rounding;
  * no acceptance gate, no per-frame scales, no multi-view rejection, no voxels;
  * the confidence filter: confidence at or below the window's 25th percentile is set to 0;
  * fusion within the window only: each frame's points are projected into the PREVIOUS frame only
    and merged one-to-one with the point there when their z agree within 5 cm (absolute), by
    confidence-weighted averaging with the confidences added; unmatched points (confidence-0 ones
    included) become new points; the window's points with confidence 0 are not exported. Frames
    shared by consecutive windows therefore appear twice, as in ScaRF's export.
Differences from the released code (on purpose): depths are sampled on DAVIO's pixel grid
(`pixel_stride`) so that densities are comparable, the range limit is DAVIO's `max_depth_m`, and
there is no per-frame or per-submap scale optimisation (notes/scarf.md §1) and no sky filter.
Evaluate its clouds voxelised at 4 cm, as the paper does ("ScaRF's EuRoC clouds voxelized to match").
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from models.da3.preprocess import camera_centres
from models.da3.similarity import Similarity
from runtime.errors import DavioError
from runtime.mapping.multiview import sample_grid
from runtime.mapping.placement import backproject
from runtime.mapping.windows import MappingWindow


@dataclass(frozen=True)
class ScarfConfig:
    """Parameters of the ScaRF-style mapper (notes/scarf.md; stride and range from MappingConfig)."""

    conf_percentile: float = 25.0
    """Confidence at or below this percentile of the window's positive confidences is set to 0."""
    merge_abs_depth_m: float = 0.05
    """A point merges with the previous frame's point at its pixel when their z differ by less than this."""
    pixel_stride: int = 4
    """Depth pixels are sampled on this grid (DAVIO's MappingConfig.pixel_stride)."""
    max_depth_m: float = 20.0
    """Depths beyond this are not mapped (DAVIO's MappingConfig.max_depth_m)."""


@dataclass
class ScarfStats:
    """Counters of the ScaRF-style mapper."""

    windows_offered: int = 0
    windows_accepted: int = 0
    model_errors: list = field(default_factory=list)
    points_sampled: int = 0
    points_new: int = 0
    points_merged: int = 0
    points_exported: int = 0


@dataclass(frozen=True)
class PlacedWindow:
    """A window placed by one similarity S = (s, R, t): camera poses T_OC (N,4,4) and depth (N,H,W)."""

    T_OC: np.ndarray
    depth: np.ndarray
    sim: Similarity


def window_similarity(T_CW_model: np.ndarray, T_OC_input: np.ndarray) -> Similarity:
    """The similarity (s, R, t) that maps the model's cameras onto the input cameras.

    R is the rotation closest to the mean of R_OC_i R_model_i^T (the camera orientations); s and t
    are then the least-squares fit of the camera centres, y = s R x + t. With consistent cameras
    this is Umeyama's fit on the centres (models/da3/similarity.py); unlike it, the rotation stays
    determined when a window's centres are (nearly) collinear, e.g. a straight flight.

    Raises:
        ValueError: the model's centres coincide (the scale is undefined).
    """
    T_WC = np.linalg.inv(np.asarray(T_CW_model, np.float64))
    T_OC = np.asarray(T_OC_input, np.float64)
    x, y = camera_centres(np.asarray(T_CW_model, np.float64)), T_OC[:, :3, 3]
    U, _, Vt = np.linalg.svd(np.einsum("nij,nkj->ik", T_OC[:, :3, :3], T_WC[:, :3, :3]))
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    xc, yc = x - x.mean(0), y - y.mean(0)
    var_x = float((xc**2).sum(1).mean())
    if var_x < 1e-18:
        raise ValueError("the model's camera centres coincide: the window scale is undefined")
    s = float((yc * (xc @ R.T)).sum(1).mean() / var_x)
    t = y.mean(0) - s * R @ x.mean(0)
    rmse = float(np.sqrt(((y - (s * x @ R.T + t)) ** 2).sum(1).mean()))
    return Similarity(s=s, R=R, t=t, rmse_y=rmse, spread_x=float(np.sqrt(var_x)))


def place_window(T_CW_model: np.ndarray, depth: np.ndarray, T_OC_input: np.ndarray) -> PlacedWindow:
    """Apply the similarity from the model's cameras to the input cameras to the whole window.

    A model camera (R_i, c_i) goes to (R R_i, s R c_i + t) and its depth to s d_i, so a point
    X = R_i d K^-1 u + c_i of the model's world goes to s R X + t.

    Args:
        T_CW_model: (N,4,4) world-to-camera poses returned by the model.
        depth: (N,H,W) depth returned by the model.
        T_OC_input: (N,4,4) the input camera poses (odometry frame, metric).

    Raises:
        ValueError: degenerate centres (the similarity scale is undefined).
    """
    T_WC = np.linalg.inv(np.asarray(T_CW_model, np.float64))
    sim = window_similarity(T_CW_model, T_OC_input)
    T = np.tile(np.eye(4), (len(T_WC), 1, 1))
    T[:, :3, :3] = np.einsum("ij,njk->nik", sim.R, T_WC[:, :3, :3])
    T[:, :3, 3] = sim.s * T_WC[:, :3, 3] @ sim.R.T + sim.t
    return PlacedWindow(T, np.asarray(depth, np.float64) * sim.s, sim)


class ScarfMapper:
    """ScaRF-style mapping of windows (module docstring); `points()` is the exported cloud.

    Args:
        model: the depth model (`model.K_rect` is the view the depth lives in).
        cfg: parameters.
    """

    def __init__(self, model: Any, cfg: ScarfConfig | None = None) -> None:
        self.model = model
        self.cfg = cfg or ScarfConfig()
        self.K = np.asarray(model.K_rect, np.float64)
        self.stats = ScarfStats()
        self._points: list[np.ndarray] = []
        self._conf: list[np.ndarray] = []

    def process(self, window: MappingWindow) -> PlacedWindow | None:
        """Map one window; returns its placement (None on a model error, counted)."""
        st = self.stats
        st.windows_offered += 1
        T_OC = np.asarray(window.T_OC, np.float64)
        n = len(window.frames)
        try:
            pred = self.model.predict(window.frames, np.tile(self.K, (n, 1, 1)), np.linalg.inv(T_OC))
            placed = place_window(pred.T_CW, pred.depth, T_OC)
        except (DavioError, ValueError, np.linalg.LinAlgError) as exc:
            st.model_errors.append(f"window {window.window_id}: {type(exc).__name__}: {exc}")
            return None
        pts, conf = self._fuse(placed, np.asarray(pred.conf, np.float64))
        keep = conf > 0
        self._points.append(pts[keep])
        self._conf.append(conf[keep])
        st.points_exported += int(keep.sum())
        st.windows_accepted += 1
        return placed

    def _fuse(self, placed: PlacedWindow, conf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The window's points: each frame merged with the previous frame's points (module docstring)."""
        cfg, st = self.cfg, self.stats
        n, h, w = placed.depth.shape
        u, v = sample_grid(h, w, cfg.pixel_stride)
        gw = len(np.arange(cfg.pixel_stride // 2, w, cfg.pixel_stride))
        gh = len(np.arange(cfg.pixel_stride // 2, h, cfg.pixel_stride))
        d = placed.depth[:, v, u]
        c = conf[:, v, u]
        valid = np.isfinite(d) & (d > 0) & (d <= cfg.max_depth_m)
        st.points_sampled += int(d.size)
        cv = c[valid & (c > 0)]
        if cv.size and cfg.conf_percentile > 0:    # ScaRF: conf <= p25 of the nonzero conf -> 0
            c = np.where(c > np.percentile(cv, cfg.conf_percentile), c, 0.0)
        P = np.zeros((0, 3))
        W = np.zeros(0)
        prev_idx: np.ndarray | None = None
        for i in range(n):
            g = np.flatnonzero(valid[i])
            X = backproject(d[i, g], self.K, u[g], v[g]) @ placed.T_OC[i, :3, :3].T + placed.T_OC[i, :3, 3]
            ci = c[i, g]
            idx = np.full(len(u), -1, np.int64)
            matched = np.zeros(len(g), bool)
            if prev_idx is not None and len(g):
                j, k = self._match_previous(X, prev_idx, placed.T_OC[i - 1], P, gw, gh)
                if j.size:
                    wsum = W[j] + ci[k]
                    safe = np.where(wsum > 0, wsum, 1.0)
                    avg = (W[j, None] * P[j] + ci[k, None] * X[k]) / safe[:, None]
                    P[j] = np.where((wsum > 0)[:, None], avg, 0.5 * (P[j] + X[k]))
                    W[j] = wsum
                    idx[g[k]] = j
                    matched[k] = True
                    st.points_merged += int(j.size)
            new = np.flatnonzero(~matched)
            idx[g[new]] = len(P) + np.arange(new.size)
            P = np.concatenate([P, X[new]])
            W = np.concatenate([W, ci[new]])
            st.points_new += int(new.size)
            prev_idx = idx
        return P, W

    def _match_previous(self, X: np.ndarray, prev_idx: np.ndarray, T_OC_prev: np.ndarray, P: np.ndarray,
                        gw: int, gh: int) -> tuple[np.ndarray, np.ndarray]:
        """(point index j, row k of X) of one-to-one matches of X with the previous frame's points."""
        cfg = self.cfg
        R, c = T_OC_prev[:3, :3], T_OC_prev[:3, 3]
        p = (X - c) @ R
        z = p[:, 2]
        zs = np.where(z > 1e-6, z, 1.0)
        pu = self.K[0, 0] * p[:, 0] / zs + self.K[0, 2]
        pv = self.K[1, 1] * p[:, 1] / zs + self.K[1, 2]
        off = cfg.pixel_stride // 2
        iu = np.round((pu - off) / cfg.pixel_stride).astype(np.int64)
        iv = np.round((pv - off) / cfg.pixel_stride).astype(np.int64)
        ok = (z > 1e-6) & (iu >= 0) & (iu < gw) & (iv >= 0) & (iv < gh)
        k = np.flatnonzero(ok)
        j = prev_idx[iv[k] * gw + iu[k]]
        has = j >= 0
        k, j = k[has], j[has]
        dz = np.abs(z[k] - ((P[j] - c) @ R)[:, 2])
        close = dz < cfg.merge_abs_depth_m
        k, j, dz = k[close], j[close], dz[close]
        order = np.lexsort((dz, j))          # one-to-one: per previous point, the closest z wins
        first = np.ones(order.size, bool)
        first[1:] = j[order][1:] != j[order][:-1]
        sel = order[first]
        return j[sel], k[sel]

    def points(self) -> tuple[np.ndarray, np.ndarray]:
        """(points (P,3) in the poses' frame, confidence sums (P,)) of every exported point."""
        if not self._points:
            return np.zeros((0, 3)), np.zeros(0)
        return np.concatenate(self._points), np.concatenate(self._conf)
