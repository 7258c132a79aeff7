"""Submap-graph configuration (paper Sec. V.C, eqs. graphres and objective).

Defaults are the paper's numbers."""
from __future__ import annotations

from dataclasses import dataclass


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
    point_sigma_min_m: float = 0.10
    """Floor of both point sigmas (m)."""
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
