"""The submap graph fed by the mapper, one node per committed submap (paper Sec. V.C).

At each commit the new submap becomes a node (initialised from the previous node's current state and
the VIO odometry between them, lambda from the shared-image link), with its odometry factor, its
shared-image scale link and its adjacent point group (`add_submap`); verified revisits add their scale
ratio and, past the drift gate, their point group (`try_revisits`, `add_revisit`). `finish_commit` then
solves the graph (up to eight LM iterations) when a scale or point constraint was added, and evicts the
oldest nodes beyond the graph's window. A filter restart (new odometry segment) starts a new graph.

Evicted nodes keep their odometry pose, time and final state here (a few hundred bytes each), and their
centre views are archived with thinning (`views.ViewStore`), so a revisit can still close a loop on an
older part of the map: the evicted node then re-enters the graph as a fixed anchor.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from runtime.graph.config import GraphConfig
from runtime.graph.factors import GraphError
from runtime.graph.graph import SolveReport, SubmapGraph
from runtime.graph.revisits import (
    RevisitConfig,
    RevisitStats,
    RevisitView,
    chain_drift_sigma,
    revisit_candidates,
    verify_revisit,
)
from runtime.graph.views import ViewStats, ViewStore, view_overlap


@dataclass
class GraphStats:
    """Counters of the graph (report.json "mapping.graph")."""

    nodes: int = 0
    segments: int = 0
    solves: int = 0
    solve_s: float = 0.0
    solve_s_max: float = 0.0
    iterations: int = 0
    odometry_factors: int = 0
    scale_links: int = 0
    point_groups_adjacent: int = 0
    point_groups_revisit: int = 0
    revisit_scale_links: int = 0
    evicted: int = 0
    anchors_added: int = 0
    candidates_low_overlap: int = 0
    last_solve: dict = field(default_factory=dict)
    revisits: RevisitStats = field(default_factory=RevisitStats)
    views: ViewStats = field(default_factory=ViewStats)


class GraphBackend:
    """Owns the SubmapGraph of the current odometry segment."""

    def __init__(self, cfg: GraphConfig | None = None, revisits: RevisitConfig | None = None) -> None:
        self.cfg = cfg or GraphConfig()
        self.revisit_cfg = revisits or RevisitConfig()
        self.graph = SubmapGraph(self.cfg)
        self.segment: int | None = None
        self.stats = GraphStats()
        self.views = ViewStore(self.revisit_cfg)
        self.stats.views = self.views.stats
        self._T_OS: dict[int, np.ndarray] = {}
        self._t_ns: dict[int, int] = {}
        self._order: list[int] = []
        self._evicted: dict[int, tuple[np.ndarray, float]] = {}
        self._constrained = False

    def state(self, j: int) -> tuple[np.ndarray, float]:
        """(T_MS_j, lambda_j) of node j (an evicted node: the state it left the graph with)."""
        if j not in self.graph and j in self._evicted:
            T, lam = self._evicted[j]
            return T.copy(), lam
        s = self.graph.node_state(j)
        return s.T_MS, s.lam

    def T_MO(self, j: int) -> np.ndarray:
        """Odometry-to-map correction defined by node j (eq. correction): T_MS_j T_S_jO."""
        return self.state(j)[0] @ np.linalg.inv(self._T_OS[j])

    def add_submap(self, j: int, T_OS: np.ndarray, segment: int, prev: int | None = None,
                   link: object | None = None, points: tuple[np.ndarray, np.ndarray] | None = None,
                   t_ns: int = 0) -> None:
        """Add submap j (odometry pose T_OS, centre time t_ns); `prev` is the previous submap of the same
        segment, `link` its ScaleLink (kappa, sigma) to j, `points` (p_prev in S_prev, p_j in S_j) its
        adjacent point group. Solved by `finish_commit`."""
        st = self.stats
        T_OS = np.asarray(T_OS, np.float64)
        if segment != self.segment:            # a new odometry frame: a new graph, gauge at identity
            self.graph = SubmapGraph(self.cfg)
            self._T_OS.clear()
            self._t_ns.clear()
            self._order.clear()
            self._evicted.clear()
            self.views.clear()
            self.segment = segment
            st.segments += 1
            prev = None
        if prev is not None and prev not in self.graph:
            prev = None
        self._T_OS[j] = T_OS
        self._t_ns[j] = int(t_ns)
        self._order.append(int(j))
        st.nodes += 1
        if prev is None or not len(self.graph):
            if not len(self.graph):          # the gauge: the first node keeps the filter's pose
                self.graph.add_node(j, T_OS, 0.0)
            else:                            # no link to the last node: carried by its correction
                last = self.graph.node_ids[-1]
                self.graph.add_node(j, self.T_MO(last) @ T_OS, self.state(last)[1])
            return
        T_MS_prev, lam_prev = self.state(prev)
        Z = np.linalg.inv(self._T_OS[prev]) @ T_OS
        kappa = float(link.kappa) if link is not None else 0.0
        self.graph.add_node(j, T_MS_prev @ Z, lam_prev + kappa)
        self.graph.add_odometry(prev, j, Z)
        st.odometry_factors += 1
        if link is not None:
            self.graph.add_scale_link(prev, j, float(link.kappa), float(link.sigma), kind=link.method)
            st.scale_links += 1
            self._constrained = True
        if points is not None and len(points[0]):
            self.graph.add_points(prev, j, points[0], points[1], adjacent=True)
            st.point_groups_adjacent += 1
            self._constrained = True

    def finish_commit(self) -> SolveReport | None:
        """Solve the graph when a scale or point constraint was added since the last commit, then evict
        the oldest nodes beyond the window. Returns the solve's report (None without a solve)."""
        rep = self.solve() if self._constrained else None
        self._constrained = False
        self._evict_excess()
        return rep

    def _evict_excess(self) -> None:
        """Evict the oldest resident nodes beyond the limit: their states are kept for revisits and
        their views archived (or thinned)."""
        extra = max(len(self.graph) - self.cfg.max_resident_nodes, 0)
        states = {k: self.state(k) for k in self.graph.node_ids[:extra]}
        for k in self.graph.evict_excess():
            self._evicted[k] = states[k]
            self.views.archive(k, states[k][0])
            self.stats.evicted += 1

    def add_view(self, j: int, features: object, view: RevisitView) -> None:
        """Keep node j's centre view (matcher features and RevisitView) for later revisits."""
        self.views.add(j, features, view)

    def candidates(self, b: int) -> list[int]:
        """Revisit candidates of node b among the nodes with a view (resident and archived): centres
        within `candidate_radius_m`, at least `min_time_gap_s` older, at least `min_view_overlap` of b's
        keypoints matchable from the candidate's view (`views.view_overlap`); largest overlap first, at
        most `max_candidates`."""
        cfg = self.revisit_cfg
        ids = [k for k in self.views.ids if k == b or k in self.graph or k in self._evicted]
        pos = np.array([self.state(k)[0][:3, 3] for k in ids]).reshape(-1, 3)
        near = revisit_candidates(ids, [self._t_ns[k] for k in ids], pos, b,
                                  replace(cfg, max_candidates=len(ids)))
        T_b, vb = self.state(b)[0], self.views.get(b)[1]
        scored = []
        for a in near:
            ov = view_overlap(self.views.get(a)[1], self.state(a)[0], vb, T_b, cfg.overlap_max_ray_angle_deg,
                              cfg.overlap_max_scale_change)
            if ov >= cfg.min_view_overlap:
                scored.append((-ov, -a))
            else:
                self.stats.candidates_low_overlap += 1
        return [-a for _, a in sorted(scored)[: max(int(cfg.max_candidates), 0)]]

    def try_revisits(self, b: int, matcher: object) -> int:
        """Look for verified revisits of node b among older nodes with a view, resident or evicted
        (`candidates`): match the centre images, verify (PnP gates, positive depth, coverage, depth
        agreement, 3-sigma innovation against the graph's prediction), and add each accepted one
        (`add_revisit`; solved by `finish_commit`). Returns the number of revisits added; every
        candidate's outcome is counted by stage."""
        if not self.revisit_cfg.enabled or b not in self.graph or b not in self.views:
            return 0
        added = 0
        fb, vb = self.views.get(b)
        for a in self.candidates(b):
            fa, va = self.views.get(a)
            m = matcher.match_features(fa, fb)
            ia, ib = self._order.index(a), self._order.index(b)
            chain = self._order[ia:ib + 1]
            Z_chain = [np.linalg.inv(self._T_OS[p]) @ self._T_OS[q]
                       for p, q in zip(chain[:-1], chain[1:], strict=True)]
            T_pred = np.linalg.inv(self.state(a)[0]) @ self.state(b)[0]
            res = verify_revisit(va, vb, (m.idx_a, m.idx_b), T_pred, chain_drift_sigma(Z_chain, self.cfg),
                                 self.revisit_cfg, self.cfg)
            self.stats.revisits.record(res)
            if res.accepted:
                self.add_revisit(a, b, res.kappa, (res.p_a, res.p_b) if res.admit_points else None)
                added += 1
        return added

    def add_revisit(self, a: int, b: int, kappa: float, points: tuple[np.ndarray, np.ndarray] | None
                    ) -> None:
        """A verified revisit: its median depth ratio as a scale link (sigma from the config) and, when
        it passed the drift gate, its point group. An evicted node a re-enters as a fixed anchor at the
        state it left with. Solved by `finish_commit`."""
        if a not in self.graph:
            if a not in self._evicted:
                raise GraphError(f"revisit {a}-{b}: node {a} is neither in the graph nor evicted")
            self.graph.add_anchor(a, *self._evicted[a])
            self.stats.anchors_added += 1
        self.graph.add_scale_link(a, b, kappa, self.cfg.revisit_scale_sigma, kind="revisit")
        self.stats.revisit_scale_links += 1
        if points is not None and len(points[0]):
            self.graph.add_points(a, b, points[0], points[1], adjacent=False)
            self.stats.point_groups_revisit += 1
        self._constrained = True

    def solve(self) -> SolveReport:
        rep = self.graph.solve(self.cfg.max_iterations)
        st = self.stats
        st.solves += 1
        st.solve_s += rep.time_s
        st.solve_s_max = max(st.solve_s_max, rep.time_s)
        st.iterations += rep.iterations
        st.last_solve = {"cost_before": rep.cost_before, "cost_after": rep.cost_after,
                         "iterations": rep.iterations, "time_s": rep.time_s, "nodes": len(self.graph)}
        return rep
