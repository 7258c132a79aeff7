"""The mapper: one accepted window -> one submap, committed to the fused map and handed to a sink.

Per window (run by the model worker, never by the tracking thread):
  1. the conditioned DA3 call and its gates (conditioned.py);
  2. per-frame scales from in-window matches (frame_scales.py);
  3. depth samples on a pixel grid, the confidence filter and multi-view rejection (multiview.py; a
     depth another image contradicts goes, one no other image sees is kept unless
     `multiview_keep_unseen` is off); a window where more than `max_multiview_failed_fraction` of the
     depths another image sees are contradicted is refused as a whole (not in the paper);
  4. the submap (frame S_j = the centre image's camera, points kept in their image's camera frame);
  5. the relative-scale link to the previous submap (shared_scale.py);
  6. fusion into voxels over the resident submaps (fusion.py): at most `max_resident_submaps` stay in
     memory; an evicted submap leaves the live grid too (its archive stays on disk, and the final
     export re-fuses every archive), so memory stays bounded on long runs;
  7. the commit: a new map version, handed to the sink (the run's map archive).
The submap graph (runtime/graph) places the submaps: each commit adds a node with its odometry
factor, shared-image scale link and adjacent point group, solves, and moves the resident submaps
whose state changed (their voxels are re-fused). `graph=False` keeps T_MS_j = T_OS_j.
"""
from __future__ import annotations

import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from models.depth_model import DepthModel
from runtime.errors import DavioError
from runtime.graph.backend import GraphBackend
from runtime.graph.config import GraphConfig, RevisitConfig
from runtime.graph.revisits import RevisitView
from runtime.mapping.conditioned import WindowFit, depth_call
from runtime.mapping.config import MappingConfig
from runtime.mapping.frame_scales import FrameScaleResult, PairMatches, solve_frame_scales
from runtime.mapping.fusion import VoxelGrid
from runtime.mapping.multiview import confidence_mask, multiview_test, sample_grid
from runtime.mapping.placement import backproject, place_points, ray_points
from runtime.mapping.rectify import Rectifier, sample_at
from runtime.mapping.shared_scale import ScaleLink, overlap_link, shared_link
from runtime.mapping.submap import Submap, SubmapState
from runtime.mapping.windows import MappingWindow

MAX_ERROR_MESSAGES = 10


@dataclass
class MappingStats:
    """Counters of the mapping layer (report.json "mapping")."""

    windows_offered: int = 0
    windows_dropped_queue: int = 0
    windows_processed: int = 0
    windows_accepted: int = 0
    windows_rejected: dict = field(default_factory=dict)
    model_errors: list = field(default_factory=list)
    points_sampled: int = 0
    rejected_invalid_depth: int = 0
    rejected_confidence: int = 0
    rejected_multiview: int = 0
    points_unverified: int = 0
    """Retained points that no other image of their window sees (MappingConfig.multiview_keep_unseen)."""
    points_retained: int = 0
    frame_scale_solves: int = 0
    frame_scale_unconstrained: int = 0
    frame_scale_matches: int = 0
    links_shared: int = 0
    links_overlap: int = 0
    links_missing: int = 0
    submaps_resident: int = 0
    submaps_evicted: int = 0
    voxels: int = 0
    map_version: int = 0
    matcher: str = ""
    stage_s: dict = field(default_factory=dict)

    def reject(self, reason: str) -> None:
        self.windows_rejected[reason] = self.windows_rejected.get(reason, 0) + 1


@dataclass
class MapCommit:
    """What one commit changed.

    Attributes:
        version: the map version this commit defines.
        submap: the new submap.
        link: its scale link to the previous submap (None when there was none).
        changed: submaps whose graph state (T_MS, lambda) the commit's solve moved: resident ones as
            Submap, ones that already left memory (still in the graph's wider window) as SubmapState.
        T_MO: (4,4) the odometry-to-map correction the commit defines (eq. correction).
        t_ns: sensor time of the newest image of the window.
    """

    version: int
    submap: Submap
    link: ScaleLink | None
    changed: list = field(default_factory=list)
    T_MO: np.ndarray = field(default_factory=lambda: np.eye(4))
    t_ns: int = 0


class Mapper:
    """Pose-conditioned dense mapping of tracking windows.

    Args:
        model: the depth model (DA3 ONNX graph or the emulated DA3); `model.K_rect` is the view.
        camera: the rig's camera model (for the rectification maps).
        cfg: mapping configuration.
        matcher: a models.matcher.Matcher for the per-frame scales (default: XFeat, ORB fallback),
            or False to skip the per-frame scales.
        sink: called with each MapCommit and the current stats (the run's map archive).
        conditioned: False runs DA3 without poses (the unconditioned reference of the benchmark).
        graph: the submap graph's configuration (None: defaults), or False to place submaps with the
            filter's poses as they are (T_MS_j = T_OS_j, lambda_j = 0: the "graph off" ablation).
        revisits: revisit retrieval and admission settings (None: defaults).
    """

    def __init__(self, model: DepthModel, camera: Any, cfg: MappingConfig | None = None,
                 matcher: Any = None, sink: Callable[[MapCommit, MappingStats], None] | None = None,
                 conditioned: bool = True, graph: GraphConfig | None | bool = None,
                 revisits: RevisitConfig | None = None) -> None:
        self.model = model
        self.cfg = cfg or MappingConfig()
        self.K = np.asarray(model.K_rect, np.float64)
        self.rectify = Rectifier(camera, self.K)
        if matcher is None:
            from models.matcher import Matcher

            matcher = Matcher.default(top_k=1024)
        self.matcher = matcher or None
        self.sink = sink
        self.conditioned = conditioned
        self.stats = MappingStats(matcher=getattr(self.matcher, "backend", "none"))
        self.grid = VoxelGrid(self.cfg.voxel_m)
        self.resident: list[Submap] = []
        self.submap_count = 0
        self._prev: tuple[Submap, dict[int, np.ndarray]] | None = None
        self._features: OrderedDict[int, Any] = OrderedDict()
        self.backend = None if graph is False else GraphBackend(graph or GraphConfig(), revisits)
        self._states: dict[int, SubmapState] = {}
        """Graph states of submaps that left memory while their node is still in the graph."""

    # ------------------------------------------------------------------ the window job
    def process(self, window: MappingWindow) -> MapCommit | WindowFit | None:
        """Map one window; returns the commit, or the refused window's WindowFit (None on a model error)."""
        st = self.stats
        st.windows_processed += 1
        t0 = time.perf_counter()
        try:
            pred, fit = depth_call(self.model, window, self.cfg, self.conditioned)
        except (DavioError, ValueError, np.linalg.LinAlgError) as exc:
            st.reject("model_error")
            if len(st.model_errors) < MAX_ERROR_MESSAGES:
                st.model_errors.append(f"window {window.window_id}: {type(exc).__name__}: {exc}")
            return None
        self._time("depth_call", t0)
        if not fit.accepted:
            st.reject(fit.reason)
            return fit
        n = len(window.frames)
        c = n // 2
        T_OC = np.asarray(window.T_OC, np.float64)
        T_OS = T_OC[c]
        T_SC = np.linalg.inv(T_OS) @ T_OC
        depth = np.asarray(pred.depth, np.float64)
        conf = np.asarray(pred.conf, np.float32)
        if self._refused_for_invalid_depth(depth):
            return replace(fit, accepted=False, reason="invalid_depth")
        t1 = time.perf_counter()
        grey = [self.rectify(f.image) for f in window.frames]
        scales = self._frame_scales(window, grey, depth, conf, T_SC)
        self._time("frame_scales", t1)
        depth *= scales.scales[:, None, None]
        t2 = time.perf_counter()
        points_C, image, pconf, pgrey, failed, judged = self._retained_points(depth, conf, grey, T_SC)
        self._time("rejection", t2)
        if judged and failed > self.cfg.max_multiview_failed_fraction * judged:
            st.reject("multiview")
            return replace(fit, accepted=False, reason="multiview")
        st.points_unverified += len(points_C) - (judged - failed)    # kept although no other image sees them
        st.points_retained += len(points_C)
        self.submap_count += 1
        st.map_version += 1
        sub = Submap(index=self.submap_count - 1, frame_t_ns=window.t_ns, centre=c, T_OS=T_OS, T_SC=T_SC,
                     K=self.K.copy(), s_hat=float(np.exp(fit.log_s_hat)), frame_scales=scales.scales,
                     points_C=points_C.astype(np.float32), image=image.astype(np.uint8),
                     conf=pconf.astype(np.float32), grey=pgrey, T_MS=T_OS.copy(), lam=0.0,
                     version=st.map_version, segment=window.segment,
                     fit={**fit.as_dict(), "window_id": window.window_id,
                          "frame_scale_rms_before": scales.rms_before,
                          "frame_scale_rms_after": scales.rms_after,
                          "frame_scale_matches": scales.matches_used})
        depths_by_t = {int(t): depth[i] for i, t in enumerate(window.t_ns)}
        link = self._link(sub, depths_by_t, T_OC)
        t_graph = time.perf_counter()
        changed = self._graph_update(sub, depths_by_t, link, grey[c])
        self._time("graph", t_graph)
        t3 = time.perf_counter()
        for other in changed:
            if isinstance(other, Submap) and self._moved_in_grid(other):
                self.refuse(other)
        self._fuse(sub)
        self.resident.append(sub)
        while len(self.resident) > self.cfg.max_resident_submaps:
            old = self.resident.pop(0)
            self._unfuse(old)               # leaves memory and the live grid; its archive stays on disk
            if self.backend is not None and old.index in self.backend.graph:
                self._states[old.index] = old.state()
            st.submaps_evicted += 1
        self._prev = (sub, depths_by_t)
        st.submaps_resident = len(self.resident)
        st.voxels = len(self.grid)
        st.windows_accepted += 1
        self._time("fusion", t3)
        T_MO = self.backend.T_MO(sub.index) if self.backend is not None else np.eye(4)
        commit = MapCommit(st.map_version, sub, link, changed, T_MO, int(window.t_ns[-1]))
        if self.sink is not None:
            t4 = time.perf_counter()
            self.sink(commit, st)
            self._time("archive", t4)
        return commit

    # ------------------------------------------------------------------ the submap graph
    def _graph_update(self, sub: Submap, depths_by_t: dict[int, np.ndarray], link: ScaleLink | None,
                      centre_image: np.ndarray) -> list[Submap]:
        """Add the submap to the graph, solve, and copy the new states to the resident submaps;
        returns the submaps (other than `sub`) whose state changed: resident ones (Submap) and ones that
        left memory while their node stays in the graph (SubmapState)."""
        if self.backend is None:
            return []
        prev = self._prev[0] if self._prev is not None and self._prev[0].segment == sub.segment else None
        points = self._adjacent_points(prev, sub, depths_by_t) if prev is not None else None
        self.backend.add_submap(sub.index, sub.T_OS, sub.segment, None if prev is None else prev.index,
                                link, points, t_ns=int(sub.frame_t_ns[sub.centre]))
        view = self._centre_view(sub, depths_by_t, centre_image)
        if view is not None:
            sub.view = view
            self.backend.add_view(sub.index, *view)
            self.backend.try_revisits(sub.index, self.matcher)
        self.backend.finish_commit()
        sub.T_MS, sub.lam = self.backend.state(sub.index)
        changed: list = []
        for other in self.resident:
            if other.index not in self.backend.graph:
                continue
            T_MS, lam = self.backend.state(other.index)
            if not (np.array_equal(T_MS, other.T_MS) and lam == other.lam):
                other.T_MS, other.lam, other.version = T_MS, lam, self.stats.map_version
                changed.append(other)
        for k in list(self._states):
            if k not in self.backend.graph:         # evicted from the graph: its state is final
                del self._states[k]
                continue
            old = self._states[k]
            T_MS, lam = self.backend.state(k)
            if not (np.array_equal(T_MS, old.T_MS) and lam == old.lam):
                self._states[k] = replace(old, T_MS=T_MS, lam=lam, version=self.stats.map_version)
                changed.append(self._states[k])
        return changed

    def _centre_view(self, sub: Submap, depths_by_t: dict[int, np.ndarray], image: np.ndarray
                     ) -> tuple | None:
        """(Features, RevisitView) of a submap's centre image (rectified grey), kept by the graph for
        revisits: pyramid features at `RevisitConfig.view_scales` when the matcher has them."""
        if self.matcher is None or self.backend is None:
            return None
        t = int(sub.frame_t_ns[sub.centre])
        f, d = self._features.get(t), depths_by_t.get(t)
        if f is None or d is None:
            return None
        scales = self.backend.revisit_cfg.view_scales
        if len(scales) > 1 and self.backend.revisit_cfg.enabled and hasattr(self.matcher, "detect_pyramid"):
            f = self.matcher.detect_pyramid(image, scales, base=f)
        h, w = d.shape
        return f, RevisitView(self.K, np.asarray(f.kpts, np.float64), sample_at(d, f.kpts), (w, h))

    def _adjacent_points(self, prev: Submap, sub: Submap, depths_by_t: dict[int, np.ndarray]
                         ) -> tuple[np.ndarray, np.ndarray] | None:
        """Up to `graph_points` correspondences between the centre images of consecutive submaps:
        (p_prev in S_prev, p_sub in S_sub), corrected depths without lambda."""
        if self.matcher is None or self._prev is None:
            return None
        t_a, t_b = int(prev.frame_t_ns[prev.centre]), int(sub.frame_t_ns[sub.centre])
        fa, fb = self._features.get(t_a), self._features.get(t_b)
        d_a, d_b = self._prev[1].get(t_a), depths_by_t.get(t_b)
        if fa is None or fb is None or d_a is None or d_b is None:
            return None
        p_a, p_b = self._matched_points(self.matcher.match_features(fa, fb), d_a, d_b)
        # keep matches the odometry does not contradict (within 25 % of depth): wrong matches go
        Z = np.linalg.inv(prev.T_OS) @ sub.T_OS
        pred = p_b @ Z[:3, :3].T + Z[:3, 3]
        ok = np.linalg.norm(pred - p_a, axis=1) <= 0.25 * p_a[:, 2]
        p_a, p_b = p_a[ok], p_b[ok]
        if len(p_a) < self.cfg.graph_min_points:
            return None
        keep = np.unique(np.linspace(0, len(p_a) - 1, min(len(p_a), self.cfg.graph_points)).astype(int))
        return p_a[keep], p_b[keep]

    # ------------------------------------------------------------------ fusion of resident submaps
    def _fuse(self, sub: Submap) -> None:
        """Add a submap to the live grid at its current state (remembered, to take it out exactly)."""
        sub.fused_state = (np.array(sub.T_MS, np.float64), float(sub.lam))
        self.grid.integrate(sub.points_M(), sub.grey)

    def _unfuse(self, sub: Submap) -> None:
        """Take a submap out of the live grid, at the state it was fused with."""
        T_MS, lam = sub.fused_state
        self.grid.integrate(place_points(sub.points_C, sub.image, sub.T_SC, T_MS, lam), sub.grey, sign=-1)
        sub.fused_state = None

    def _moved_in_grid(self, sub: Submap) -> bool:
        """The graph moved the submap by more than `refuse_tolerance_m` at its farthest point since it was
        fused (smaller moves stay in the live grid as fused; the archive and the export use the state)."""
        if sub.fused_state is None:
            return True
        T_old, lam_old = sub.fused_state
        d = float(np.max(np.linalg.norm(sub.points_C, axis=1))) if sub.n_points else 0.0
        dT = np.linalg.inv(T_old) @ sub.T_MS
        rot = float(np.linalg.norm(dT[:3, :3] - np.eye(3)))   # ~ angle (rad) for small rotations
        move = np.linalg.norm(dT[:3, 3]) + rot * d + abs(sub.lam - lam_old) * d
        return move > self.cfg.refuse_tolerance_m

    def refuse(self, sub: Submap) -> None:
        """Move a resident submap in the live grid after the graph changed its T_MS or lambda."""
        self._unfuse(sub)
        self._fuse(sub)

    # ------------------------------------------------------------------ stages
    def _time(self, stage: str, t0: float) -> None:
        self.stats.stage_s[stage] = self.stats.stage_s.get(stage, 0.0) + time.perf_counter() - t0

    def _features_of(self, t_ns: int, image: np.ndarray) -> Any:
        if t_ns in self._features:
            return self._features[t_ns]
        f = self.matcher.detect(image)
        self._features[t_ns] = f
        if len(self._features) > 2 * self.cfg.window_images:
            self._features.popitem(last=False)
        return f

    def _matched_points(self, m: Any, d_a: np.ndarray, d_b: np.ndarray, ok_a: np.ndarray | None = None,
                        ok_b: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Back-projected matches (p_a (K,3), p_b (K,3)) in their cameras, for the matched pixels where
        both depth maps hold a valid depth (finite, > 0, < max_depth_m) and both masks (if given) hold."""
        za, zb = sample_at(d_a, m.points_a), sample_at(d_b, m.points_b)
        good = (za > 0) & (zb > 0) & (za < self.cfg.max_depth_m) & (zb < self.cfg.max_depth_m)  # NaN: False
        if ok_a is not None:
            good &= sample_at(ok_a, m.points_a, False) & sample_at(ok_b, m.points_b, False)
        ua, ub = m.points_a[good], m.points_b[good]
        ua, ub = np.round(ua), np.round(ub)
        return (backproject(za[good], self.K, ua[:, 0], ua[:, 1]),
                backproject(zb[good], self.K, ub[:, 0], ub[:, 1]))

    def _frame_scales(self, window: MappingWindow, grey: list[np.ndarray], depth: np.ndarray,
                      conf: np.ndarray, T_SC: np.ndarray) -> FrameScaleResult:
        n = len(window.frames)
        cfg = self.cfg
        if self.matcher is None:
            return FrameScaleResult(np.ones(n))
        feats = [self._features_of(int(f.t_ns), g) for f, g in zip(window.frames, grey, strict=True)]
        ok_conf = confidence_mask(conf, cfg.conf_percentile)
        pairs = []
        for off in cfg.frame_scale_pair_offsets:
            for i in range(n - off):
                j = i + off
                m = self.matcher.match_features(feats[i], feats[j])
                if len(m) < cfg.frame_scale_min_matches:
                    continue
                pi, pj = self._matched_points(m, depth[i], depth[j], ok_conf[i], ok_conf[j])
                if len(pi) >= cfg.frame_scale_min_matches:
                    pairs.append(PairMatches(i, j, pi, pj))
        res = solve_frame_scales(pairs, T_SC, cfg.frame_scale_rounds, cfg.frame_scale_prior_sigma,
                                 cfg.frame_scale_huber, cfg.frame_scale_min_matches)
        if res.rounds:
            self.stats.frame_scale_solves += 1
            self.stats.frame_scale_matches += res.matches_used
        else:
            self.stats.frame_scale_unconstrained += 1
        return res

    def _refused_for_invalid_depth(self, depth: np.ndarray) -> bool:
        """True (counted) when fewer than `min_valid_depth_fraction` of the window's grid depths are finite
        and in (0, max_depth_m]."""
        cfg, st = self.cfg, self.stats
        u, v = sample_grid(depth.shape[1], depth.shape[2], cfg.pixel_stride)
        d = depth[:, v, u]
        valid = int(np.count_nonzero(np.isfinite(d) & (d > 0) & (d <= cfg.max_depth_m)))
        if valid >= cfg.min_valid_depth_fraction * d.size:
            return False
        st.points_sampled += int(d.size)
        st.rejected_invalid_depth += int(d.size - valid)
        st.reject("invalid_depth")
        return True

    def _retained_points(self, depth: np.ndarray, conf: np.ndarray, grey: list[np.ndarray],
                         T_SC: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, int]:
        """Grid samples that pass the range, confidence and multi-view tests (counted): camera points,
        image index, confidence, grey, and how many depths another image sees (judged) and of those fail
        the test (failed)."""
        cfg, st = self.cfg, self.stats
        n, h, w = depth.shape
        u, v = sample_grid(h, w, cfg.pixel_stride)
        d = depth[:, v, u]                               # (N, G)
        c = conf[:, v, u]
        valid = np.isfinite(d) & (d > 0) & (d <= cfg.max_depth_m)
        st.points_sampled += int(d.size)
        st.rejected_invalid_depth += int((~valid).sum())
        ok_c = valid & confidence_mask(np.where(valid, c, np.nan), cfg.conf_percentile)
        st.rejected_confidence += int((valid & ~ok_c).sum())
        img_idx, g_idx = np.nonzero(ok_c)
        pts_C = backproject(d[img_idx, g_idx], self.K, u[g_idx], v[g_idx])
        R, t = T_SC[img_idx, :3, :3], T_SC[img_idx, :3, 3]
        pts_S = np.einsum("pij,pj->pi", R, pts_C) + t
        dmaps = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan)
        agree, seen = multiview_test(pts_S, img_idx, T_SC, dmaps, self.K, cfg.multiview_rel_depth)
        keep = agree | ~seen if cfg.multiview_keep_unseen else agree
        st.rejected_multiview += int((~keep).sum())
        img_idx, g_idx = img_idx[keep], g_idx[keep]
        grey_vals = np.stack([g[v, u] for g in grey])[img_idx, g_idx].astype(np.uint8)
        failed, judged = int((seen & ~agree).sum()), int(seen.sum())
        points_C = ray_points(d[img_idx, g_idx], self.K, u[g_idx], v[g_idx])   # as the archive reads them
        return points_C, img_idx, c[img_idx, g_idx], grey_vals, failed, judged

    def _link(self, sub: Submap, depths_by_t: dict[int, np.ndarray], T_OC: np.ndarray) -> ScaleLink | None:
        """kappa_ab to the previous submap of the same segment (shared images, else projected overlap)."""
        if self._prev is None or self._prev[0].segment != sub.segment:
            return None
        prev, prev_depths = self._prev
        cfg = self.cfg
        link = shared_link(prev.index, sub.index, prev_depths, depths_by_t, cfg.min_overlap_pixels,
                           cfg.min_scale_sigma)
        if link is None:
            # nearest camera of the previous submap to the new centre sees most of the same surface
            T_OC_prev = prev.T_OS @ prev.T_SC
            k = int(np.argmin(np.linalg.norm(T_OC_prev[:, :3, 3] - sub.T_OS[:3, 3], axis=1)))
            P_O = (sub.T_OS @ np.c_[sub.points_S(), np.ones(sub.n_points)].T).T[:, :3]
            t_prev = int(prev.frame_t_ns[k])
            link = overlap_link(prev.index, sub.index, P_O, T_OC_prev[k], prev_depths[t_prev], self.K,
                                cfg.min_overlap_pixels, cfg.min_scale_sigma)
        if link is None:
            self.stats.links_missing += 1
        else:
            if link.method == "shared":
                self.stats.links_shared += 1
            else:
                self.stats.links_overlap += 1
        return link

    # ------------------------------------------------------------------ results
    def fused_points(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(positions (V,3), grey (V,), counts (V,)) of the live map: the resident submaps fused
        (map frame). The whole map of a long run is the archive's export."""
        return self.grid.points()
