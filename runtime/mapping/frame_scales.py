"""Per-frame depth scales of a window from in-window matches (paper Sec. V.B, eq. framescale).

For match k between images i and i' (one or two positions apart) with back-projected points
p_ik = s_hat d_i(u_ik) K^-1 u_ik in C_i, the residual

    r_ii'k = T_SC_i (s_i p_ik) - T_SC_i' (s_i' p_i'k)

is affine in the scales. Eight rounds of depth-normalised, outlier-reweighted (Huber) linear least
squares (Cauchy weights)
with a weak unit prior; after each round the scales are projected onto sum_i log s_i = 0
(unit geometric mean), so they only redistribute relative corrections within the window.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class PairMatches:
    """Matched camera-frame points of images i and j of a window (metres, s_hat applied).

    Attributes:
        i, j: image indices in the window.
        p_i, p_j: (K,3) points p_ik in C_i and p_jk in C_j.
    """

    i: int
    j: int
    p_i: np.ndarray
    p_j: np.ndarray


@dataclass
class FrameScaleResult:
    """Solved per-frame scales.

    Attributes:
        scales: (N,) per-frame scales, unit geometric mean (all ones when nothing constrained them).
        rounds: IRLS rounds run.
        matches_used: matches that entered the solve.
        inlier_fraction: share of matches whose depth-normalised residual is within `huber` at the end.
        rms_before, rms_after: RMS depth-normalised residual at unit scales and at the fitted scales
            (before the unit-geometric-mean projection).
    """

    scales: np.ndarray
    rounds: int = 0
    matches_used: int = 0
    inlier_fraction: float = float("nan")
    rms_before: float = float("nan")
    rms_after: float = float("nan")
    pairs: list = field(default_factory=list)


def _residuals(s: np.ndarray, pairs: list[PairMatches], T_SC: np.ndarray) -> list[np.ndarray]:
    """Depth-normalised residual norms per pair at scales s."""
    out = []
    for pm in pairs:
        Ri, ti = T_SC[pm.i, :3, :3], T_SC[pm.i, :3, 3]
        Rj, tj = T_SC[pm.j, :3, :3], T_SC[pm.j, :3, 3]
        r = s[pm.i] * pm.p_i @ Ri.T + ti - (s[pm.j] * pm.p_j @ Rj.T + tj)
        depth = 0.5 * (pm.p_i[:, 2] + pm.p_j[:, 2])
        out.append(np.linalg.norm(r, axis=1) / depth)
    return out


def solve_frame_scales(pairs: list[PairMatches], T_SC: np.ndarray, rounds: int = 8,
                       prior_sigma: float = 0.1, huber: float = 0.05,
                       min_matches: int = 20) -> FrameScaleResult:
    """Solve the per-frame scales s_i of a window.

    Args:
        pairs: matches between images of the window (pairs with fewer than `min_matches` are ignored).
        T_SC: (N,4,4) metric poses of the images relative to the submap frame.
        rounds: IRLS rounds.
        prior_sigma: sigma of the unit prior s_i ~ 1, in units of the depth-normalised residual.
        huber: scale of the Cauchy weights 1 / (1 + (r / huber)^2) on the depth-normalised residual norm.

    Returns:
        FrameScaleResult; scales stay at 1 for images no retained pair touches.
    """
    T_SC = np.asarray(T_SC, np.float64)
    n = T_SC.shape[0]
    pairs = [pm for pm in pairs if len(pm.p_i) >= min_matches and pm.i != pm.j
             and np.isfinite(pm.p_i).all() and np.isfinite(pm.p_j).all()
             and (pm.p_i[:, 2] > 0).all() and (pm.p_j[:, 2] > 0).all()]
    s = np.ones(n)
    res = FrameScaleResult(s.copy(), pairs=[(pm.i, pm.j, len(pm.p_i)) for pm in pairs])
    if not pairs:
        return res
    res.matches_used = int(sum(len(pm.p_i) for pm in pairs))
    r0 = np.concatenate(_residuals(s, pairs, T_SC))
    res.rms_before = float(np.sqrt(np.mean(r0**2)))
    weights = [np.ones(len(pm.p_i)) for pm in pairs]
    s_fit = s
    for _ in range(rounds):
        H = np.eye(n) / prior_sigma**2
        g = np.ones(n) / prior_sigma**2
        for pm, w in zip(pairs, weights, strict=True):
            Ri, ti = T_SC[pm.i, :3, :3], T_SC[pm.i, :3, 3]
            Rj, tj = T_SC[pm.j, :3, :3], T_SC[pm.j, :3, 3]
            a = pm.p_i @ Ri.T                 # (K,3): d r / d s_i
            b = -(pm.p_j @ Rj.T)              # (K,3): d r / d s_j
            c = tj - ti                       # r = a s_i + b s_j - c
            depth = 0.5 * (pm.p_i[:, 2] + pm.p_j[:, 2])
            ww = w / depth**2                 # depth normalisation and robust weight
            H[pm.i, pm.i] += np.sum(ww * np.sum(a * a, 1))
            H[pm.j, pm.j] += np.sum(ww * np.sum(b * b, 1))
            hij = np.sum(ww * np.sum(a * b, 1))
            H[pm.i, pm.j] += hij
            H[pm.j, pm.i] += hij
            g[pm.i] += np.sum(ww * (a @ c))
            g[pm.j] += np.sum(ww * (b @ c))
        s_new = np.linalg.solve(H, g)
        if not (np.isfinite(s_new).all() and (s_new > 0).all()):
            break
        s = s_new / np.exp(np.mean(np.log(s_new)))   # unit geometric mean
        res.rounds += 1
        # robust weights from the fitted scales (the common factor is the graph's lambda, not an outlier)
        s_fit = s_new
        rs = _residuals(s_new, pairs, T_SC)
        weights = [1.0 / (1.0 + (r / huber) ** 2) for r in rs]   # Cauchy: outliers fade out
    r1 = np.concatenate(_residuals(s_fit, pairs, T_SC))
    res.rms_after = float(np.sqrt(np.mean(r1**2)))
    res.inlier_fraction = float(np.mean(r1 <= huber))
    res.scales = s
    return res
