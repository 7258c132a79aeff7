"""Submap-graph and revisit configuration (paper Sec. V.C, eqs. graphres and objective, "Submap graph and
revisit admission").

Defaults are the paper's numbers."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from models.matcher.features import pyramid_scales
from models.matcher.pnp import PnPGates
from runtime.config_checks import at_least, in_range, non_negative, positive
from runtime.errors import ConfigError


@dataclass
class GraphConfig:
    """The gravity-preserving submap graph: factor noise models, robust loss and solver limits."""

    drift_trans_sigma_min_m: float = 0.02
    """Odometry drift model, translation: sigma_t = max(this, drift_trans_sigma_per_m |t_ab|) (m)."""
    drift_trans_sigma_per_m: float = 0.005
    """... growth of the translation sigma with the VIO distance |t_ab| between centres (m per m)."""
    drift_rot_sigma_min_deg: float = 0.5
    """Odometry drift model, rotation: sigma_r = max(this, drift_rot_sigma_per_m_deg |t_ab|) (deg)."""
    drift_rot_sigma_per_m_deg: float = 0.5
    """... growth of the rotation sigma with |t_ab| (deg per m)."""
    point_sigma_along_frac: float = 0.10
    """Point covariance: sigma along the viewing ray as a fraction of the point's depth (range, m/m)."""
    point_sigma_across_frac: float = 0.01
    """Point covariance: sigma across the viewing ray as a fraction of the point's depth (m/m)."""
    point_sigma_min_m: float = 0.05
    """Floor of both point sigmas (m). The paper: 0.10. Measured against the truth (V1_02 and MH_03
    simulations, every point group's residual at the true submap poses and log-depth scales): across the
    ray 0.7-1.3 % of depth as the model says, i.e. 2.4-5.1 cm RMS at the room's 3.7 m median depth, where
    a 10 cm floor overstated it 2-4x and the graph under-used its revisits (V1_02 final / odometry
    0.66-0.77 over seeds 0-3, 0.57-0.68 with 5 cm); at the hall's 9 m the 1 % term exceeds either floor
    (BENCHMARKS.md "The point-sigma floor measured")."""
    scale_prior_sigma: float = 0.10
    """Prior |lambda_j - lambda_0| / this on every estimated lambda (every non-gauge node's, and the gauge's
    with `gauge_lambda_free`; log-scale units; lambda_0 = 0: the first node's initial lambda, the
    filter's metric scale, also after evictions)."""
    gauge_lambda_free: bool = True
    """True (default): the gauge node fixes only its pose; its lambda is estimated with the same prior as
    every other node's, so a wrong depth scale of the first submap (or of the gauge after evictions) is
    not imposed on its neighbours. False: the paper's gauge, which also fixes lambda_0 = 0. Not the paper:
    on the IMU-consistent V1_02 recording the paper's gauge leaves the lambdas worse than none at all
    (lambda - lambda* RMS 0.059-0.064 against 0.048-0.062 with lambda = 0, seeds 0-2; the first window's
    depths follow the filter's scale just after start-up), the free gauge better on all 12
    seed-sequence pairs than lambda = 0; F@10 +0.032 on average over those 12, +0.09 to +0.12 on V1_02,
    -0.02 to -0.05 on MH_03 (BENCHMARKS.md "the gauge's own lambda")."""
    huber_threshold: float = 2.0
    """Huber threshold on each whitened residual block norm: rho(r) = r^2/2 (r <= k), k r - k^2/2 beyond.
    `math.inf` gives the plain quadratic loss."""
    max_iterations: int = 8
    """Levenberg-Marquardt iterations per solve (trial steps; a rejected step counts)."""
    revisit_scale_sigma: float = 0.03
    """sigma_ab of the scale link a verified revisit's median depth ratio adds (log-scale units)."""
    max_resident_nodes: int = 64
    """Nodes kept in the graph; `SubmapGraph.evict_excess` drops the oldest beyond this (not in the paper,
    which bounds the fused submaps at 24: a node costs only its pose, lambda and factors, so the graph
    keeps about 96 s of windows and a revisit can still move the first pass over a place; measured on the
    MH_03 simulation, final/odometry ATE 0.77 with 24 nodes, 0.66 with 48, 0.64 with 64)."""
    blas_threads: int | None = 1
    """BLAS threads during a solve (threadpoolctl; None leaves the process setting). The solve's small
    dense products run fastest on one thread; threads on shared cores cost 10x more."""

    def __post_init__(self) -> None:
        s = "graph"
        positive(self, s, "drift_trans_sigma_min_m", "drift_rot_sigma_min_deg", "point_sigma_min_m",
                 "scale_prior_sigma", "revisit_scale_sigma")
        positive(self, s, "huber_threshold", finite=False)
        non_negative(self, s, "drift_trans_sigma_per_m", "drift_rot_sigma_per_m_deg",
                     "point_sigma_along_frac", "point_sigma_across_frac")
        at_least(self, s, 1, "max_iterations")
        at_least(self, s, 2, "max_resident_nodes")
        if self.blas_threads is not None:
            at_least(self, s, 1, "blas_threads")


@dataclass
class RevisitConfig:
    """Revisit retrieval and admission (paper defaults)."""

    candidate_radius_m: float = 8.0
    """Candidates: centres of S_a and S_b within this distance in the map frame (m)."""
    min_time_gap_s: float = 5.0
    """Candidates: centre-image timestamps at least this far apart (s)."""
    max_candidates: int = 3
    """Candidates tried per new submap, largest view overlap first (not in the paper)."""
    min_view_overlap: float = 0.25
    """Candidates: at least this share of the new centre view's keypoints must land in the candidate's
    image by the graph's current poses (`views.view_overlap`; not in the paper: centres within 8 m
    that face away cannot match)."""
    overlap_max_ray_angle_deg: float = 30.0
    """View overlap: a point counts when the rays to it from the two centres are at most this far apart ..."""
    overlap_max_scale_change: float = 1.5
    """... and its ranges from the two centres within this factor (`views.view_overlap`)."""
    view_scales: tuple[float, ...] = (1.0, 0.7, 0.5)
    """Image-pyramid scales of the centre views' features (`Matcher.detect_pyramid`; 1024 + 502 + 256
    XFeat keypoints at the mapper's top_k of 1024), matched level pair by level pair, so a place seen
    again from 1.4x nearer or farther or more still matches (XFeat's descriptors are single-scale; ORB
    keeps its own pyramid); the candidate search admits up to `overlap_max_scale_change`. (1.0,) = the
    single-scale features of the frame-scale step. Not in the paper: on the V1_02 simulation, pairs 5 s
    apart with at least 30 % true overlap pass the match and inlier counts 38 times in 60 against 17
    single-scale (BENCHMARKS.md)."""
    max_views: int = 600
    """Centre views archived for revisits once their node is evicted (`views.ViewStore`); beyond this,
    evicted views are dropped (counted). About 290 kB each with the pyramid's 1782 XFeat keypoints
    (170 kB single-scale; 600 views: 176 MB)."""
    view_thin_radius_m: float = 1.0
    """An evicted view is not archived when an archived view's centre lies within this distance (m) ..."""
    view_thin_angle_deg: float = 30.0
    """... and its optical axis within this angle (deg): the older view of the place is kept."""
    pnp: PnPGates = field(default_factory=PnPGates)
    """PnP-RANSAC gates: >= 50 matches, >= 30 inliers, inlier fraction >= 0.25, 2 px."""
    coverage_grid: int = 4
    """Image coverage: b's image is cut into coverage_grid x coverage_grid cells (not in the paper)."""
    min_coverage_cells: int = 6
    """Image coverage: cells of b's image holding at least one verified inlier needed (6 of 16: a
    verified region of about 3/8 of the image; not in the paper)."""
    max_depth_rel_error: float = 0.2
    """Depth agreement: median |z_pred - d_b| / d_b over the inliers must not exceed this."""
    innovation_sigmas: float = 3.0
    """Innovation test: every component of Log(T_pred^-1 T_pnp) within this many combined sigmas."""
    innovation_scale_sigma: float = 0.10
    """Innovation test: relative uncertainty of a's depth scale, which scales the PnP translation
    (default = the graph's scale prior `GraphConfig.scale_prior_sigma`; not in the paper)."""
    max_correspondences: int = 80
    """Point group size: at most this many verified correspondences, spread over b's image."""
    scale_sigma: float = 0.03
    """sigma_ab of the revisit's median-depth-ratio scale link (log-scale units); mirrors
    `GraphConfig.revisit_scale_sigma`, which `GraphBackend.add_revisit` uses."""
    enabled: bool = True
    """Look for revisits at all (off: the "without revisits" ablation)."""
    drift_gate: bool = True
    """Admit a verified revisit's point group only past the drift gate (off: always; an ablation)."""

    def __post_init__(self) -> None:
        try:
            self.view_scales = pyramid_scales(self.view_scales)
        except ValueError as exc:
            raise ValueError(f"view_scales: {exc}") from None
        s = "revisits"
        positive(self, s, "candidate_radius_m", "max_depth_rel_error", "innovation_sigmas", "scale_sigma")
        non_negative(self, s, "min_time_gap_s", "view_thin_radius_m", "view_thin_angle_deg",
                     "innovation_scale_sigma")
        in_range(self, s, "min_view_overlap", 0.0, 1.0)
        in_range(self, s, "overlap_max_ray_angle_deg", 0.0, 180.0, lo_open=True)
        in_range(self, s, "overlap_max_scale_change", 1.0, math.inf, hi_open=True)
        at_least(self, s, 1, "max_candidates", "coverage_grid", "max_correspondences")
        at_least(self, s, 0, "max_views", "min_coverage_cells")
        if self.min_coverage_cells > self.coverage_grid ** 2:
            raise ConfigError(f"revisits.min_coverage_cells must be at most revisits.coverage_grid^2 "
                              f"({self.coverage_grid ** 2}), got {self.min_coverage_cells}")
