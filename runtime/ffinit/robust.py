"""Stratified LMedS over the point system and the acceptance gates (paper Sec. IV-B).

Residuals are used scale-normalized, r_k = e_k / s (approx. normalized reprojection error), so
scoring by med r removes the bias toward small scale and all thresholds are scale-free.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from runtime.ffinit.config import FFInitConfig
from runtime.ffinit.linear import (
    LinearSolution,
    PointSystem,
    build_system,
    check_conditioning,
    weighted_solve,
)
from runtime.ffinit.window import InitWindow, Rejection


@dataclass
class RobustResult:
    """An accepted robust solution.

    Attributes:
        solution: refitted [s, v0, g] on the inliers (g refined onto |g| = g0).
        inliers: (K,) bool mask over the points of `system`.
        system: the point system (image 0 excluded).
        inlier_fraction: inliers / points.
        median_residual: median scale-normalized residual of the inliers.
        threshold: the inlier threshold used.
        hypotheses_admissible: how many LMedS hypotheses passed per-image admissibility.
    """

    solution: LinearSolution
    inliers: np.ndarray
    system: PointSystem
    inlier_fraction: float
    median_residual: float
    threshold: float
    hypotheses_admissible: int


def _admissible_images(r: np.ndarray, image: np.ndarray, thr: float) -> int:
    count = 0
    for i in np.unique(image):
        m = image == i
        if np.count_nonzero(r[m] <= thr) * 2 > np.count_nonzero(m):
            count += 1
    return count


def _threshold(r: np.ndarray, cfg: FFInitConfig) -> float:
    return max(cfg.inlier_sigma_factor * 1.4826 * float(np.median(r)), cfg.min_inlier_threshold)


def robust_solve(window: InitWindow, cfg: FFInitConfig | None = None) -> RobustResult | Rejection:
    """Conditioning gates, stratified LMedS, refit on inliers, acceptance gates."""
    cfg = cfg or FFInitConfig()
    system = build_system(window)
    rej = check_conditioning(window, system, cfg)
    if rej is not None:
        return rej
    rng = np.random.default_rng(cfg.seed)
    per_image = [np.flatnonzero(system.image == i) for i in np.unique(system.image)]
    per_image = [idx for idx in per_image if len(idx) >= cfg.points_per_image_hypothesis]
    if 1 + len(per_image) < cfg.min_images:
        return Rejection("too_few_images", "not enough images with two points for LMedS")

    best: tuple[float, LinearSolution] | None = None
    admissible = 0
    for _ in range(cfg.lmeds_hypotheses):
        pick = np.concatenate([rng.choice(idx, cfg.points_per_image_hypothesis, replace=False)
                               for idx in per_image])
        hyp = weighted_solve(system.subset(pick), cfg.gravity, 0)
        if hyp is None or not hyp.scale > 0:
            continue
        r = system.residuals(hyp.x) / hyp.scale
        if _admissible_images(r, system.image, _threshold(r, cfg)) < cfg.min_admissible_images:
            continue
        admissible += 1
        score = float(np.median(r))
        if best is None or score < best[0]:
            best = (score, hyp)
    if best is None:
        return Rejection("no_admissible_hypothesis",
                         f"none of {cfg.lmeds_hypotheses} hypotheses had s > 0 and "
                         f">= {cfg.min_admissible_images} consistent images")

    r_best = system.residuals(best[1].x) / best[1].scale
    thr = _threshold(r_best, cfg)
    inliers = r_best <= thr
    sol = weighted_solve(system.subset(inliers), cfg.gravity, cfg.gravity_refinements,
                         cfg.gravity_magnitude == "absorb_bias")
    if sol is None or not sol.scale > 0:
        return Rejection("refit_failed", "refit on inliers gave no positive scale")
    r = system.residuals(sol.x) / sol.scale
    inliers = r <= thr
    frac = float(np.count_nonzero(inliers)) / len(system)
    med = float(np.median(r[inliers])) if np.any(inliers) else float("inf")
    result = RobustResult(sol, inliers, system, frac, med, thr, admissible)
    return accept(window, result, cfg)


def accept(window: InitWindow, result: RobustResult, cfg: FFInitConfig) -> RobustResult | Rejection:
    """Support and physical-plausibility gates of Sec. IV-B."""
    if result.inlier_fraction < cfg.min_inlier_fraction:
        return Rejection("low_inlier_fraction",
                         f"{result.inlier_fraction:.2f} < {cfg.min_inlier_fraction}")
    if result.median_residual > cfg.max_median_residual:
        return Rejection("high_median_residual",
                         f"{result.median_residual:.4f} > {cfg.max_median_residual}")
    bias = float(np.linalg.norm(result.solution.ba))
    if bias > cfg.max_accel_bias:
        return Rejection("implausible_gravity_magnitude",
                         f"gravity magnitude off g0 by {bias:.2f} m/s^2 > {cfg.max_accel_bias}")
    speed = float(np.linalg.norm(result.solution.v0))
    if speed > cfg.max_velocity:
        return Rejection("implausible_velocity", f"|v0| = {speed:.2f} m/s > {cfg.max_velocity}")
    f = window.mean_specific_force_I0()
    g = result.solution.g
    cosang = float(f @ g / max(np.linalg.norm(f) * np.linalg.norm(g), 1e-12))
    angle = float(np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0))))
    if angle > cfg.max_gravity_angle_deg:
        return Rejection("gravity_disagrees",
                         f"gravity {angle:.1f} deg from mean specific force > {cfg.max_gravity_angle_deg}")
    return result
