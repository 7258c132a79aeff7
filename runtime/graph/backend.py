"""The submap graph fed by the mapper, one node per committed submap (paper Sec. V.C).

At each commit the new submap becomes a node (initialised from the previous node's current state and
the VIO odometry between them, lambda from the shared-image link), with its odometry factor, its
shared-image scale link and its adjacent point group; whenever a scale or point constraint was added
the graph is solved (up to eight LM iterations). Revisits add their scale ratio and, past the drift
gate, their point group (`add_revisit`). A filter restart (new odometry segment) starts a new graph.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from runtime.graph.config import GraphConfig
from runtime.graph.graph import SolveReport, SubmapGraph
from runtime.graph.revisits import (
    RevisitConfig,
    RevisitStats,
    RevisitView,
    chain_drift_sigma,
    revisit_candidates,
    verify_revisit,
)


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
    last_solve: dict = field(default_factory=dict)
    revisits: RevisitStats = field(default_factory=RevisitStats)


class GraphBackend:
    """Owns the SubmapGraph of the current odometry segment."""

    def __init__(self, cfg: GraphConfig | None = None, revisits: RevisitConfig | None = None) -> None:
        self.cfg = cfg or GraphConfig()
        self.revisit_cfg = revisits or RevisitConfig()
        self.graph = SubmapGraph(self.cfg)
        self.segment: int | None = None
        self.stats = GraphStats()
        self._T_OS: dict[int, np.ndarray] = {}
        self._t_ns: dict[int, int] = {}

    def state(self, j: int) -> tuple[np.ndarray, float]:
        """(T_MS_j, lambda_j) of node j."""
        s = self.graph.node_state(j)
        return s.T_MS, s.lam

    def T_MO(self, j: int) -> np.ndarray:
        """Odometry-to-map correction defined by node j (eq. correction): T_MS_j T_S_jO."""
        return self.state(j)[0] @ np.linalg.inv(self._T_OS[j])

    def add_submap(self, j: int, T_OS: np.ndarray, segment: int, prev: int | None = None,
                   link: object | None = None, points: tuple[np.ndarray, np.ndarray] | None = None,
                   t_ns: int = 0) -> SolveReport | None:
        """Add submap j (odometry pose T_OS); `prev` is the previous submap of the same segment, `link`
        its ScaleLink (kappa, sigma) to j, `points` (p_prev in S_prev, p_j in S_j) its adjacent point
        group. Returns the solve's report when the graph was solved."""
        st = self.stats
        T_OS = np.asarray(T_OS, np.float64)
        if segment != self.segment:            # a new odometry frame: a new graph, gauge at identity
            self.graph = SubmapGraph(self.cfg)
            self._T_OS.clear()
            self._t_ns.clear()
            self.segment = segment
            st.segments += 1
            prev = None
        if prev is not None and prev not in self.graph:
            prev = None
        self._T_OS[j] = T_OS
        self._t_ns[j] = int(t_ns)
        st.nodes += 1
        if prev is None or not len(self.graph):
            if not len(self.graph):          # the gauge: the first node keeps the filter's pose
                self.graph.add_node(j, T_OS, 0.0)
            else:                            # no link to the last node: carried by its correction
                last = self.graph.node_ids[-1]
                self.graph.add_node(j, self.T_MO(last) @ T_OS, self.state(last)[1])
            return None
        T_MS_prev, lam_prev = self.state(prev)
        Z = np.linalg.inv(self._T_OS[prev]) @ T_OS
        kappa = float(link.kappa) if link is not None else 0.0
        self.graph.add_node(j, T_MS_prev @ Z, lam_prev + kappa)
        self.graph.add_odometry(prev, j, Z)
        st.odometry_factors += 1
        constrained = False
        if link is not None:
            self.graph.add_scale_link(prev, j, float(link.kappa), float(link.sigma), kind=link.method)
            st.scale_links += 1
            constrained = True
        if points is not None and len(points[0]):
            self.graph.add_points(prev, j, points[0], points[1], adjacent=True)
            st.point_groups_adjacent += 1
            constrained = True
        rep = self.solve() if constrained else None
        for k in self.graph.evict_excess():
            self._T_OS.pop(k, None)
            self._t_ns.pop(k, None)
            st.evicted += 1
        return rep

    def try_revisits(self, b: int, views: dict[int, tuple[object, RevisitView]], matcher: object) -> int:
        """Look for verified revisits of node b among older resident nodes (within 8 m, >= 5 s apart):
        match the centre images, verify (PnP gates, positive depth, coverage, depth agreement, 3-sigma
        innovation against the graph's prediction), and add each accepted one (`add_revisit`).
        `views` maps node ids to (matcher Features of the centre image, RevisitView). Returns the
        number of revisits added; every candidate's outcome is counted by stage."""
        if not self.revisit_cfg.enabled or b not in self.graph or b not in views:
            return 0
        ids = [k for k in self.graph.node_ids if k in views]
        pos = np.array([self.state(k)[0][:3, 3] for k in ids]).reshape(-1, 3)
        cands = revisit_candidates(ids, [self._t_ns[k] for k in ids], pos, b, self.revisit_cfg)
        added = 0
        for a in cands:
            fa, va = views[a]
            fb, vb = views[b]
            m = matcher.match_features(fa, fb)
            chain = self.graph.node_ids
            ia, ib = chain.index(a), chain.index(b)
            Z_chain = [np.linalg.inv(self._T_OS[chain[k]]) @ self._T_OS[chain[k + 1]] for k in range(ia, ib)]
            T_pred = np.linalg.inv(self.state(a)[0]) @ self.state(b)[0]
            res = verify_revisit(va, vb, (m.idx_a, m.idx_b), T_pred, chain_drift_sigma(Z_chain, self.cfg),
                                 self.revisit_cfg, self.cfg)
            self.stats.revisits.record(res)
            if res.accepted:
                self.add_revisit(a, b, res.kappa, (res.p_a, res.p_b) if res.admit_points else None)
                added += 1
        return added

    def add_revisit(self, a: int, b: int, kappa: float, points: tuple[np.ndarray, np.ndarray] | None
                    ) -> SolveReport:
        """A verified revisit: its median depth ratio as a scale link (sigma from the config) and, when
        it passed the drift gate, its point group. Solves the graph."""
        self.graph.add_scale_link(a, b, kappa, self.cfg.revisit_scale_sigma, kind="revisit")
        self.stats.revisit_scale_links += 1
        if points is not None and len(points[0]):
            self.graph.add_points(a, b, points[0], points[1], adjacent=False)
            self.stats.point_groups_revisit += 1
        return self.solve()

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
