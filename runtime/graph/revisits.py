"""Revisit candidates and their verification (paper Sec. V.C, "Submap graph and revisit admission").

Pure computation on the centre images of two submaps a (older) and b (newer):

1. `revisit_candidates`: older nodes within 8 m of the new node's centre and at least 5 s apart.
2. `verify_revisit`: too-few-matches gate, PnP-RANSAC gates (`models.matcher.pnp.verify_pnp`),
   positive depth, image coverage, depth agreement and the 3-sigma odometry-innovation test. An
   accepted revisit yields up to 80 point correspondences (p_a in S_a, p_b in S_b) and the median log
   depth ratio for the revisit scale link. PnP only verifies: its pose is never returned as a factor.
3. `drift_gate`: the point group enters the graph only if the predicted odometry drift between the
   two submaps (`chain_drift_sigma`) exceeds the revisit's own uncertainty: the relative pose its
   correspondences measure, a's depth scale included (`revisit_pose_sigma`); the scale link always
   enters. (Measured on the EuRoC-trajectory simulations, against the group's position sigma as the
   graph weighs it (`group_position_sigma`, 1/N): V1_02 final/odometry ATE 0.77 instead of 0.95, MH_03
   0.643 instead of 0.642; the graph's weighting leaves the group one point's worth either way.)

Conventions. T_AB maps B to A. Pose uncertainties and innovations are 6-vectors [rho (m), phi (rad)]
in the order of `se3_log` and of the odometry whitening (`whitening.odometry_weights`): a right
perturbation T_SaSb Exp(xi), i.e. expressed in S_b, the same convention as the graph's odometry
residual r_o = Log(Z_ab^-1 Q_a^-1 Q_b).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from models.matcher.pnp import verify_pnp
from runtime.geometry.se3 import se3_inverse, se3_log
from runtime.geometry.so3 import skew
from runtime.graph.config import GraphConfig, RevisitConfig
from runtime.graph.factors import GraphError, check_pose
from runtime.graph.whitening import drift_sigmas, ray_covariance

STAGES = ("matches", "pnp", "positive_depth", "coverage", "depth_agreement", "degenerate", "innovation")
"""Rejection stages of `verify_revisit`, in the order they are tested."""


@dataclass
class RevisitView:
    """A submap's centre image as the revisit test sees it.

    Attributes:
        K: (3,3) intrinsics of the rectified centre image (pixels).
        kpts: (N,2) keypoints (u, v) in that image, pixels, (0, 0) = centre of the top-left pixel.
        depth_at_kpts: (N,) corrected z-depth (metres along the optical axis, without the graph's
            lambda) at the keypoints; NaN (or <= 0) where invalid.
        image_size: (width, height) in pixels.
    """

    K: np.ndarray
    kpts: np.ndarray
    depth_at_kpts: np.ndarray
    image_size: tuple[int, int]

    def __post_init__(self) -> None:
        self.K = np.asarray(self.K, np.float64)
        self.kpts = np.asarray(self.kpts, np.float64)
        self.depth_at_kpts = np.asarray(self.depth_at_kpts, np.float64)
        n = len(self.kpts)
        if self.K.shape != (3, 3) or not np.all(np.isfinite(self.K)) or min(self.K[0, 0], self.K[1, 1]) <= 0:
            raise GraphError(f"RevisitView.K must be finite (3,3) intrinsics, got {self.K.shape}")
        if self.kpts.ndim != 2 or self.kpts.shape[1] != 2 or self.depth_at_kpts.shape != (n,):
            raise GraphError(f"RevisitView needs (N,2) kpts and (N,) depths, got {self.kpts.shape} and "
                             f"{self.depth_at_kpts.shape}")
        w, h = (int(s) for s in self.image_size)
        if w <= 0 or h <= 0:
            raise GraphError(f"RevisitView.image_size must be a positive (width, height): {self.image_size}")
        self.image_size = (w, h)

    def points(self, idx: np.ndarray) -> np.ndarray:
        """(K,3) back-projected keypoints idx in the view's frame S: d K^-1 [u, v, 1] (NaN if invalid)."""
        uv1 = np.column_stack([self.kpts[idx], np.ones(len(idx))])
        d = self.depth_at_kpts[idx]
        d = np.where(np.isfinite(d) & (d > 0), d, np.nan)
        return d[:, None] * np.linalg.solve(self.K, uv1.T).T


@dataclass
class RevisitResult:
    """Outcome of `verify_revisit`.

    Attributes:
        accepted: every test passed.
        stage: 'accepted' or the failed test, one of `STAGES` (for counters).
        reason: a human-readable reason with the gated numbers.
        n_matches, n_inliers, inlier_fraction: PnP gate quantities (inliers as PnP counts them).
        n_verified: inliers with positive depth in both views (valid depth in b).
        coverage_cells: occupied cells of b's image.
        depth_rel_error: median |z_pred - d_b| / d_b of the verified inliers.
        innovation: (6,) Log(T_SaSb_pred^-1 T_SaSb_pnp) = [rho (m), phi (rad)].
        innovation_bound: (6,) k sqrt(sigma_pred^2 + revisit_sigma^2).
        p_a, p_b: (K,3) correspondences (K <= 80) in S_a and S_b from each view's own depths.
        log_depth_ratio: m = median log(d_b / z_pred) over the verified inliers (b's depth vs a's, in b).
        kappa: -m, the scale link lambda_b - lambda_a = kappa (as `mapping.shared_scale`).
        scale_sigma: sigma of that scale link.
        sigma_pred: (6,) the predicted drift sigmas given to the test.
        revisit_sigma: (6,) the measured pose's own sigmas in the innovation test (`revisit_pose_sigma`).
        position_sigma: (3,) the point group's position sigmas in the graph (`group_position_sigma`).
        admit_points: `drift_gate(sigma_pred, revisit_sigma[:3])`: add the point group, not only the scale.
    """

    accepted: bool
    stage: str
    reason: str
    n_matches: int = 0
    n_inliers: int = 0
    inlier_fraction: float = 0.0
    n_verified: int = 0
    coverage_cells: int = 0
    depth_rel_error: float = float("nan")
    innovation: np.ndarray | None = None
    innovation_bound: np.ndarray | None = None
    p_a: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    p_b: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    log_depth_ratio: float = float("nan")
    kappa: float = float("nan")
    scale_sigma: float = float("nan")
    sigma_pred: np.ndarray | None = None
    revisit_sigma: np.ndarray | None = None
    position_sigma: np.ndarray | None = None
    admit_points: bool = False

    def as_dict(self) -> dict:
        def vec(x: np.ndarray | None) -> list | None:
            return None if x is None else [float(v) for v in x]

        return {"accepted": self.accepted, "stage": self.stage, "reason": self.reason,
                "n_matches": self.n_matches, "n_inliers": self.n_inliers,
                "inlier_fraction": self.inlier_fraction, "n_verified": self.n_verified,
                "coverage_cells": self.coverage_cells, "depth_rel_error": self.depth_rel_error,
                "innovation": vec(self.innovation), "innovation_bound": vec(self.innovation_bound),
                "n_points": int(len(self.p_a)), "kappa": self.kappa, "scale_sigma": self.scale_sigma,
                "revisit_sigma": vec(self.revisit_sigma), "position_sigma": vec(self.position_sigma),
                "admit_points": self.admit_points}


@dataclass
class RevisitStats:
    """Counters of revisit tests (report.json): attempts, acceptances, rejections per stage."""

    attempts: int = 0
    accepted: int = 0
    point_groups: int = 0
    rejected: dict = field(default_factory=lambda: {s: 0 for s in STAGES})

    def record(self, res: RevisitResult) -> None:
        self.attempts += 1
        if res.accepted:
            self.accepted += 1
            self.point_groups += int(res.admit_points)
        else:
            self.rejected[res.stage] = self.rejected.get(res.stage, 0) + 1


def revisit_candidates(node_ids: Sequence[int], node_t_ns: Sequence[int], node_positions_M: np.ndarray,
                       new_id: int, cfg: RevisitConfig) -> list[int]:
    """Older nodes whose centres lie within `candidate_radius_m` of the new node's centre and whose
    centre images are at least `min_time_gap_s` older, nearest first, at most `max_candidates`.

    Args:
        node_ids: (N,) node ids (the new node among them); node_t_ns: (N,) int64 centre-image times (ns);
        node_positions_M: (N,3) centre positions in the map frame (m), e.g. T_MS_j[:3, 3].
    """
    ids = [int(i) for i in node_ids]
    t = np.asarray(node_t_ns, np.int64)
    P = np.asarray(node_positions_M, np.float64)
    if t.shape != (len(ids),) or P.shape != (len(ids), 3):
        raise GraphError(f"need N ids, (N,) times and (N,3) positions, got {len(ids)}, {t.shape}, {P.shape}")
    if int(new_id) not in ids:
        raise GraphError(f"new node {new_id} is not among the nodes")
    k = ids.index(int(new_id))
    gap_ns = int(round(cfg.min_time_gap_s * 1e9))
    dist = np.linalg.norm(P - P[k], axis=1)
    ok = (t <= t[k] - gap_ns) & (dist <= cfg.candidate_radius_m) & np.isfinite(dist)
    ok[k] = False
    order = sorted(np.flatnonzero(ok), key=lambda i: (dist[i], -int(t[i])))
    return [ids[i] for i in order[: max(int(cfg.max_candidates), 0)]]


def _adjoint(T: np.ndarray) -> np.ndarray:
    """(6,6) Ad(T) for xi = [rho, phi]: Exp(Ad(T) xi) = T Exp(xi) T^-1."""
    R, t = T[:3, :3], T[:3, 3]
    A = np.zeros((6, 6))
    A[:3, :3] = R
    A[:3, 3:] = skew(t) @ R
    A[3:, 3:] = R
    return A


def chain_drift_sigma(Z_chain: Sequence[np.ndarray], cfg: GraphConfig | None = None) -> np.ndarray:
    """(6,) predicted drift sigmas [rho (m), phi (rad)] of T_SaSb = Z_1 Z_2 ... Z_n from the drift model.

    Each odometry edge Z_i = T_S_{i-1}S_i is perturbed on the right by an independent xi_i with the
    drift model's sigmas at |t_i| (`whitening.drift_sigmas`, the model behind W_o); to first order the
    chain's right perturbation is sum_i Ad((Z_{i+1} ... Z_n)^-1) xi_i, so rotation drift early in the
    chain grows into translation drift at b. Returns the square roots of that covariance's diagonal.
    """
    cfg = cfg or GraphConfig()
    Zs = [check_pose(Z, f"Z_chain[{i}]") for i, Z in enumerate(Z_chain)]
    cov = np.zeros((6, 6))
    tail = np.eye(4)                                    # Z_{i+1} ... Z_n
    for Z in reversed(Zs):
        s_t, s_r = drift_sigmas(float(np.linalg.norm(Z[:3, 3])), cfg)
        A = _adjoint(se3_inverse(tail))
        cov += A @ np.diag([s_t**2] * 3 + [s_r**2] * 3) @ A.T
        tail = Z @ tail
    return np.sqrt(np.diag(cov))


def pair_covariances(p_a: np.ndarray, p_b: np.ndarray, R_SaSb: np.ndarray,
                     cfg: GraphConfig | None = None) -> np.ndarray:
    """(K,3,3) covariances (m^2), in S_b axes, of r_k = R_SaSb^T (p_ak - T_SaSb p_bk) under the graph's
    ray-aligned point model: R^T C(p_ak) R + C(p_bk) (`whitening.ray_covariance`)."""
    cfg = cfg or GraphConfig()
    p_a = np.asarray(p_a, np.float64)
    p_b = np.asarray(p_b, np.float64)
    R = np.asarray(R_SaSb, np.float64)
    if p_a.ndim != 2 or p_a.shape[1] != 3 or p_b.shape != p_a.shape or not np.all(np.isfinite(p_a + p_b)):
        raise GraphError(f"need finite (K,3) point pairs, got {p_a.shape} and {p_b.shape}")
    return np.einsum("ji,njk,kl->nil", R, ray_covariance(p_a, cfg), R) + ray_covariance(p_b, cfg)


def group_position_sigma(p_a: np.ndarray, p_b: np.ndarray, R_SaSb: np.ndarray,
                         cfg: GraphConfig | None = None) -> np.ndarray:
    """(3,) position sigmas (m, S_b axes) of a point group as the graph weighs it: with the 1/N factor
    of eq. objective the group is worth one point whose information is the MEAN of the pairs'
    information, so Sigma = (mean_k Sigma_k^-1)^-1 (`pair_covariances`). Its diagonal's square root."""
    S = pair_covariances(p_a, p_b, R_SaSb, cfg)
    if not len(S):
        raise GraphError("an empty point group has no position uncertainty")
    return np.sqrt(np.diag(np.linalg.inv(np.linalg.inv(S).mean(axis=0))))


def revisit_pose_sigma(p_a: np.ndarray, p_b: np.ndarray, T_SaSb: np.ndarray, scale_sigma: float,
                       cfg: GraphConfig | None = None) -> np.ndarray:
    """(6,) sigmas [rho (m), phi (rad)] of a relative pose T_SaSb measured from K point pairs (right
    perturbation, S_b axes): the measurement uncertainty the innovation test adds to the prediction's.

    Two parts, added as variances: (1) the weighted least-squares covariance (sum_k J_k^T Sigma_k^-1
    J_k)^-1 of r_k = p_ak - T_SaSb Exp(xi) p_bk, J_k = -R [I, -[p_bk]x], pairs independent with the
    ray-aligned covariances; (2) the depth scale of a, which scales the measured translation as a whole:
    a relative scale error sigma_s moves it by sigma_s t_SbSa (S_b axes, per component).
    Raises GraphError when the pairs do not constrain all six directions.
    """
    T = check_pose(T_SaSb, "T_SaSb")
    S = pair_covariances(p_a, p_b, T[:3, :3], cfg)
    p_b = np.asarray(p_b, np.float64)
    if len(p_b) < 3:
        raise GraphError(f"{len(p_b)} correspondences do not constrain a relative pose")
    A = np.zeros((len(p_b), 3, 6))
    A[:, :, :3] = np.eye(3)
    A[:, :, 3:] = -skew(p_b)                                 # d(Exp(xi) p_b)/d xi = [I, -[p_b]x]
    H = np.einsum("nji,njk,nkl->il", A, np.linalg.inv(S), A)
    if np.linalg.cond(H) > 1e12:
        raise GraphError(f"{len(p_b)} correspondences do not constrain a relative pose")
    var = np.diag(np.linalg.inv(H)).copy()
    var[:3] += (scale_sigma * (T[:3, :3].T @ T[:3, 3])) ** 2     # R^T t_SaSb = -t_SbSa
    return np.sqrt(var)


def drift_gate(sigma_pred: np.ndarray, revisit_sigma: np.ndarray) -> bool:
    """True when a verified revisit's point group may enter the graph (and move poses).

    Compares translation only, by RMS magnitude (sqrt of the trace of the 3x3 covariance): the
    predicted odometry drift |sigma_pred[:3]| against the revisit's translation uncertainty
    |revisit_sigma| (`revisit_pose_sigma`[:3]), both in metres; open when the drift is strictly larger.
    sigma_pred: (6,) [rho, phi] or (3,) translation sigmas; revisit_sigma: (3,).
    """
    sp = np.asarray(sigma_pred, np.float64).ravel()
    ps = np.asarray(revisit_sigma, np.float64).ravel()
    if sp.shape not in ((3,), (6,)) or ps.shape != (3,):
        raise GraphError(f"drift_gate needs (6,) or (3,) and (3,) sigmas, got {sp.shape} and {ps.shape}")
    return bool(np.linalg.norm(sp[:3]) > np.linalg.norm(ps))


def _cells(uv: np.ndarray, size: tuple[int, int], n: int) -> np.ndarray:
    """Flat cell index of each pixel on an n x n grid over an image of (width, height)."""
    cx = np.clip(np.floor((uv[:, 0] + 0.5) * n / size[0]), 0, n - 1).astype(np.int64)
    cy = np.clip(np.floor((uv[:, 1] + 0.5) * n / size[1]), 0, n - 1).astype(np.int64)
    return cy * n + cx


def _spread(cells: np.ndarray, err: np.ndarray, k: int) -> np.ndarray:
    """Up to k positions into `cells`, taken round-robin over the cells, lowest error first in each."""
    queues = [list(np.flatnonzero(cells == c)[np.argsort(err[cells == c], kind="stable")])
              for c in np.unique(cells)]
    out: list[int] = []
    depth = 0
    while len(out) < k and any(depth < len(q) for q in queues):
        out.extend(q[depth] for q in queues if depth < len(q))
        depth += 1
    return np.array(out[:k], np.int64)


def verify_geometry(a: RevisitView, b: RevisitView, matches_ab: tuple[np.ndarray, np.ndarray],
                    cfg: RevisitConfig) -> tuple[RevisitResult, np.ndarray | None, np.ndarray, np.ndarray]:
    """The image-geometry tests of `verify_revisit`, without any prediction: raw match count, PnP-RANSAC
    of a's back-projected keypoints (S_a) against b's pixels with the PnP gates, positive depth,
    coverage of b's image and depth agreement; then up to `max_correspondences` inliers spread over b's
    image, best reprojection first. Also the check of a map session against another (`relocalize`).

    Returns:
        (result, T_SaSb, p_a, p_b): on a failed test the result names its stage and T_SaSb is None; when
        every test passed the result is not yet accepted (its stage is 'accepted', n_* and
        depth_rel_error, log_depth_ratio filled), T_SaSb is the (4,4) PnP pose of S_b in S_a and p_a,
        p_b the (K,3) selected correspondences in S_a and S_b from each view's own depths.
    """
    none = np.zeros((0, 3))
    ia = np.asarray(matches_ab[0], np.int64).ravel()
    ib = np.asarray(matches_ab[1], np.int64).ravel()
    if ia.shape != ib.shape:
        raise GraphError(f"match index arrays differ in length: {ia.shape} vs {ib.shape}")
    if len(ia) and (ia.min() < 0 or ia.max() >= len(a.kpts) or ib.min() < 0 or ib.max() >= len(b.kpts)):
        raise GraphError("match indices out of range of the keypoints")
    gates = cfg.pnp
    n = len(ia)
    if n < gates.min_matches:
        return (RevisitResult(False, "matches", f"too few matches ({n} < {gates.min_matches})", n_matches=n),
                None, none, none)

    # PnP-RANSAC: a's points (S_a) seen at b's pixels -> T_SbSa (a NaN depth drops its match).
    P_a = a.points(ia)
    pnp = verify_pnp(P_a, b.kpts[ib], b.K, gates)
    res = RevisitResult(False, "pnp", pnp.reason, n_matches=n, n_inliers=pnp.n_inliers,
                        inlier_fraction=pnp.inlier_fraction)
    if not pnp.accepted:
        return res, None, none, none
    T_SbSa = pnp.T_CW
    inl = pnp.inliers

    # Positive depth: in front of b by the PnP pose, valid depths in a (finite points) and in b.
    z_pred = (P_a[inl] @ T_SbSa[:3, :3].T + T_SbSa[:3, 3])[:, 2]
    d_b = b.depth_at_kpts[ib[inl]]
    pos = (z_pred > 0) & np.isfinite(d_b) & (d_b > 0) & (P_a[inl, 2] > 0)
    inl, z_pred, d_b = inl[pos], z_pred[pos], d_b[pos]
    res.n_verified = len(inl)
    if len(inl) < gates.min_inliers:
        res.stage = "positive_depth"
        res.reason = f"too few inliers with positive depth ({len(inl)} < {gates.min_inliers})"
        return res, None, none, none

    # Coverage of b's image.
    uv_b = b.kpts[ib[inl]]
    cells = _cells(uv_b, b.image_size, cfg.coverage_grid)
    res.coverage_cells = int(len(np.unique(cells)))
    if res.coverage_cells < cfg.min_coverage_cells:
        res.stage = "coverage"
        res.reason = (f"inliers cover {res.coverage_cells} < {cfg.min_coverage_cells} cells of "
                      f"{cfg.coverage_grid}x{cfg.coverage_grid}")
        return res, None, none, none

    # Depth agreement of a's points moved into b against b's own depths.
    res.depth_rel_error = float(np.median(np.abs(z_pred - d_b) / d_b))
    if not res.depth_rel_error <= cfg.max_depth_rel_error:
        res.stage = "depth_agreement"
        res.reason = f"median relative depth error {res.depth_rel_error:.3f} > {cfg.max_depth_rel_error}"
        return res, None, none, none
    res.log_depth_ratio = float(np.median(np.log(d_b / z_pred)))

    # The point group: up to max_correspondences inliers spread over b's image, best reprojection first.
    uv_pred = (P_a[inl] @ T_SbSa[:3, :3].T + T_SbSa[:3, 3]) @ b.K.T
    err = np.linalg.norm(uv_pred[:, :2] / uv_pred[:, 2:] - uv_b, axis=1)
    sel = inl[_spread(cells, err, cfg.max_correspondences)]
    res.stage, res.reason = "accepted", "accepted"
    return res, se3_inverse(T_SbSa), P_a[sel], b.points(ib[sel])


def verify_revisit(a: RevisitView, b: RevisitView, matches_ab: tuple[np.ndarray, np.ndarray],
                   T_SaSb_pred: np.ndarray, sigma_pred: np.ndarray, cfg: RevisitConfig,
                   graph_cfg: GraphConfig | None = None) -> RevisitResult:
    """Verify a revisit candidate between the centre images of submaps a (older) and b.

    Args:
        a, b: the two centre images (keypoints with corrected depths).
        matches_ab: (idx_a, idx_b), kpts a[idx_a[k]] <-> b[idx_b[k]] (e.g. `Matches.idx_a, .idx_b`).
        T_SaSb_pred: (4,4) the graph's current prediction of the pose of S_b in S_a.
        sigma_pred: (6,) its predicted drift sigmas [rho (m), phi (rad)] (e.g. `chain_drift_sigma`).
        cfg: the revisit gates; graph_cfg: the point model (ray covariance) of the graph.

    Tests, in order (`STAGES`): raw match count; PnP-RANSAC of a's back-projected keypoints (S_a)
    against b's pixels, giving T_SbSa, with the PnP gates; positive depth (inliers in front of b by the
    PnP pose, with valid depths in a and b, still >= pnp.min_inliers); coverage of b's image by those
    inliers; depth agreement median |z_pred - d_b| / d_b (these five: `verify_geometry`); innovation
    |Log(T_pred^-1 T_pnp)|_i <= k sqrt(sigma_pred_i^2 + revisit_sigma_i^2) for all six components,
    revisit_sigma = the pose sigmas measured by the selected pairs plus a's depth-scale uncertainty
    (`revisit_pose_sigma`). The PnP pose is used for these tests only; the drift gate compares
    sigma_pred with revisit_sigma.
    """
    gcfg = graph_cfg or GraphConfig()
    T_pred = check_pose(T_SaSb_pred, "T_SaSb_pred")
    sp = np.asarray(sigma_pred, np.float64)
    if sp.shape != (6,) or not np.all(np.isfinite(sp)) or np.any(sp < 0):
        raise GraphError(f"sigma_pred must be 6 finite sigmas >= 0, got {sigma_pred!r}")
    res, T_pnp, p_a, p_b = verify_geometry(a, b, matches_ab, cfg)
    if T_pnp is None:
        return res
    try:
        rs = revisit_pose_sigma(p_a, p_b, T_pnp, cfg.innovation_scale_sigma, gcfg)
    except GraphError as exc:
        res.stage, res.reason = "degenerate", str(exc)
        return res
    res.sigma_pred, res.revisit_sigma = sp, rs
    res.position_sigma = group_position_sigma(p_a, p_b, T_pnp[:3, :3], gcfg)

    # Innovation of the PnP pose against the graph's prediction.
    e = se3_log(se3_inverse(T_pred) @ T_pnp)
    bound = cfg.innovation_sigmas * np.sqrt(sp**2 + rs**2)
    res.innovation, res.innovation_bound = e, bound
    if np.any(np.abs(e) > bound):
        worst = int(np.argmax(np.abs(e) / bound))
        names = ("x", "y", "z", "rx", "ry", "rz")
        res.stage = "innovation"
        res.reason = (f"innovation {names[worst]} = {e[worst]:.3f} beyond {cfg.innovation_sigmas:g} sigma "
                      f"({bound[worst]:.3f})")
        return res

    res.accepted, res.stage, res.reason = True, "accepted", "accepted"
    res.p_a, res.p_b = p_a, p_b
    res.kappa, res.scale_sigma = -res.log_depth_ratio, float(cfg.scale_sigma)
    res.admit_points = drift_gate(sp, rs[:3]) if cfg.drift_gate else True
    return res
