"""The point–inertial linear system in x = [s, v0, g] (paper eqs. 3–5) and its conditioning gates.

For point k of image i (normalized coordinates z, DA3 depth d, DA3 point p_ik in C0):
    A_ik = [B R_IC p_ik, -dt_i B, 0.5 dt_i^2 B],  B = H_ik R_CI R_IiI0,
    b_ik = B dp_i - H_ik R_CI (R_IiI0 - I) p_IC,
with H_ik = [[1, 0, -z_x], [0, 1, -z_y]]. Each row pair is divided by d and weighted by sqrt(conf),
so the residual approximates s times the normalized reprojection error.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from runtime.ffinit.config import FFInitConfig
from runtime.ffinit.window import InitWindow, Rejection


@dataclass
class PointSystem:
    """All rows of the window, image 0 excluded (its rows vanish: w_0 = 0).

    Attributes:
        A: (K, 2, 7) per-point row pairs, already divided by depth (unweighted).
        b: (K, 2) right-hand sides, divided by depth.
        w: (K,) sqrt(confidence) weights.
        image: (K,) image index of each point.
        b_ba: (K, 2, 3) d b / d ba: how the right-hand sides move with the accelerometer bias (in I_i,
            through the preintegration's J_p_ba), divided by depth.
    """

    A: np.ndarray
    b: np.ndarray
    w: np.ndarray
    image: np.ndarray
    b_ba: np.ndarray

    def __len__(self) -> int:
        return int(self.A.shape[0])

    def subset(self, mask: np.ndarray) -> PointSystem:
        return PointSystem(self.A[mask], self.b[mask], self.w[mask], self.image[mask], self.b_ba[mask])

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """(K,) algebraic residual norms |A_k x - b_k| (approx. s * reprojection error)."""
        return np.linalg.norm(self.A @ x - self.b, axis=1)


@dataclass
class LinearSolution:
    """x = [s, v0 (3), g (3)] in I0; gravity has norm g0 after refinement.

    ba: (3,) accelerometer bias in I0 implied by the gravity magnitude the data asked for
    (zero unless FFInitConfig.gravity_magnitude == "absorb_bias").
    """

    x: np.ndarray
    ba: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def scale(self) -> float:
        return float(self.x[0])

    @property
    def v0(self) -> np.ndarray:
        return self.x[1:4]

    @property
    def g(self) -> np.ndarray:
        return self.x[4:7]


def _apply_H(v: np.ndarray, zx: np.ndarray, zy: np.ndarray) -> np.ndarray:
    """H_ik v_k for stacked (K, 3) vectors -> (K, 2)."""
    return np.stack([v[:, 0] - zx * v[:, 2], v[:, 1] - zy * v[:, 2]], axis=1)


def build_system(window: InitWindow) -> PointSystem:
    """Stack the depth-divided row pairs of every non-reference image."""
    R_CI = window.R_IC.T
    blocks_A, blocks_b, blocks_w, blocks_i, blocks_ba = [], [], [], [], []
    for i in range(1, window.num_images):
        obs = window.images[i]
        if len(obs.z) == 0:
            continue
        M = R_CI @ window.R_I0Ii[i].T  # R_CI R_IiI0
        zx, zy = obs.z[:, 0], obs.z[:, 1]

        q = obs.points_C0 @ window.R_IC.T @ M.T  # B R_IC p_ik before H: M R_IC p_ik
        col_s = _apply_H(q, zx, zy)
        HB = np.stack([M[0][None, :] - zx[:, None] * M[2][None, :],
                       M[1][None, :] - zy[:, None] * M[2][None, :]], axis=1)  # (K, 2, 3)
        dt = window.dt[i]
        A = np.concatenate([col_s[:, :, None], -dt * HB, 0.5 * dt * dt * HB], axis=2)
        lever = R_CI @ (window.R_I0Ii[i].T - np.eye(3)) @ window.p_IC
        b = HB @ window.dp[i] - _apply_H(np.broadcast_to(lever, (len(zx), 3)), zx, zy)
        inv_d = 1.0 / obs.depth
        blocks_A.append(A * inv_d[:, None, None])
        blocks_b.append(b * inv_d[:, None])
        blocks_w.append(np.sqrt(np.maximum(obs.conf, 0.0)))
        blocks_i.append(np.full(len(zx), i))
        blocks_ba.append((HB @ window.J_p_ba[i]) * inv_d[:, None, None])
    if not blocks_A:
        return PointSystem(np.zeros((0, 2, 7)), np.zeros((0, 2)), np.zeros(0), np.zeros(0, int),
                           np.zeros((0, 2, 3)))
    return PointSystem(np.concatenate(blocks_A), np.concatenate(blocks_b), np.concatenate(blocks_w),
                       np.concatenate(blocks_i), np.concatenate(blocks_ba))


def _tangent_basis(g_dir: np.ndarray) -> np.ndarray:
    """(3, 2) orthonormal basis N of the plane orthogonal to unit vector g_dir."""
    a = np.array([1.0, 0.0, 0.0]) if abs(g_dir[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    b1 = np.cross(g_dir, a)
    b1 /= np.linalg.norm(b1)
    b2 = np.cross(g_dir, b1)
    return np.column_stack([b1, b2])


def weighted_solve(system: PointSystem, g0: float, refinements: int,
                   absorb_bias: bool = False) -> LinearSolution | None:
    """Weighted least squares for x, then `refinements` tangent-plane refinements of g on |g| = g0.

    absorb_bias: an accelerometer bias along gravity is indistinguishable from the gravity
    magnitude within a window; with True the magnitude stays free (the unconstrained solution, whose
    direction is then optimal), g is reported with norm g0 and the excess (|g| - g0) g_hat is
    returned as the implied accelerometer bias instead of being forced into s and v0.
    """
    if len(system) == 0:
        return None
    W = system.w[:, None]
    A = (system.A * W[:, :, None]).reshape(-1, 7)
    b = (system.b * W).reshape(-1)
    x, *_ = np.linalg.lstsq(A, b, rcond=None)
    if not np.all(np.isfinite(x)):
        return None
    g = x[4:7]
    norm = float(np.linalg.norm(g))
    if norm < 1e-9 or refinements <= 0:
        return LinearSolution(x)
    if absorb_bias:
        g_hat = g / norm
        return LinearSolution(np.concatenate([x[:4], g0 * g_hat]), (norm - g0) * g_hat)
    g = g / norm * g0
    for _ in range(refinements):
        N = _tangent_basis(g / g0)
        # unknowns [s, v0, w]; g = g + N w
        A_r = np.concatenate([A[:, :4], A[:, 4:7] @ N], axis=1)
        b_r = b - A[:, 4:7] @ g
        y, *_ = np.linalg.lstsq(A_r, b_r, rcond=None)
        g = g + N @ y[4:6]
        g = g / np.linalg.norm(g) * g0
        x = np.concatenate([y[:4], g])
    return LinearSolution(np.asarray(x, dtype=float))


def scale_bias_sensitivity(system: PointSystem, solution: LinearSolution) -> float:
    """How far an accelerometer bias moves the solved scale: |d s / d ba| / s, per m/s^2.

    The system is taken as the gravity-magnitude-constrained solve sees it (unknowns s, v0 and the
    two tangent directions of g at the solution): a bias along gravity cannot be absorbed by g and
    must be explained by s and v0; without acceleration beyond gravity (constant velocity, pure
    rotation, hover) it moves s without bound. The worst bias direction is taken (largest singular
    value of the 1 x 3 sensitivity row, i.e. its norm). Infinite when the reduced system is singular.
    """
    if len(system) == 0 or not solution.scale > 0:
        return float("inf")
    W = system.w[:, None]
    A = (system.A * W[:, :, None]).reshape(-1, 7)
    B = (system.b_ba * W[:, :, None]).reshape(-1, 3)
    g = solution.g
    N = _tangent_basis(g / np.linalg.norm(g))
    A_r = np.concatenate([A[:, :4], A[:, 4:7] @ N], axis=1)
    norms = np.linalg.norm(A_r, axis=0)
    if np.any(norms < 1e-12):
        return float("inf")
    U, sv, Vt = np.linalg.svd(A_r / norms, full_matrices=False)
    if not sv[-1] > sv[0] * 1e-12:
        return float("inf")
    dy = (Vt.T / sv) @ (U.T @ B)  # (6, 3): d y_equilibrated / d ba
    ds_dba = dy[0] / norms[0]
    return float(np.linalg.norm(ds_dba) / solution.scale)


def singular_value_ratio(system: PointSystem) -> float:
    """sigma_min / sigma_max of the weighted system with unit-norm columns (column equilibration)."""
    A = (system.A * system.w[:, None, None]).reshape(-1, 7)
    norms = np.linalg.norm(A, axis=0)
    if np.any(norms < 1e-12):
        return 0.0
    sv = np.linalg.svd(A / norms, compute_uv=False)
    return float(sv[-1] / sv[0])


def baseline_to_depth(window: InitWindow) -> float:
    """Largest DA3 camera-centre distance to view 0 over the median DA3 depth of the window."""
    depths = np.concatenate([o.depth for o in window.images if len(o.depth)])
    if depths.size == 0:
        return 0.0
    baseline = max(float(np.linalg.norm(o.p_C0Ci)) for o in window.images)
    return baseline / float(np.median(depths))


def check_conditioning(window: InitWindow, system: PointSystem, cfg: FFInitConfig) -> Rejection | None:
    """Gates (i)–(iii) of Sec. IV-B (baseline before conditioning: it is cheaper and names
    pure rotation precisely); returns the first failed gate or None."""
    used = 1 + len(np.unique(system.image)) if len(system) else (1 if window.images else 0)
    if used < cfg.min_images:
        return Rejection("too_few_images", f"{used} images with points < {cfg.min_images}")
    btd = baseline_to_depth(window)
    if btd < cfg.min_baseline_to_depth:
        return Rejection("small_baseline",
                         f"baseline-to-depth {btd:.4f} < {cfg.min_baseline_to_depth}"
                         " (e.g. pure rotation)")
    ratio = singular_value_ratio(system)
    if ratio < cfg.min_singular_ratio:
        return Rejection("ill_conditioned",
                         f"singular-value ratio {ratio:.2e} < {cfg.min_singular_ratio:.0e}"
                         " (e.g. constant-velocity motion)")
    return None


def solve_linear(window: InitWindow, cfg: FFInitConfig | None = None) -> LinearSolution | Rejection:
    """Conditioning-checked weighted solution of the whole window (no outlier handling)."""
    cfg = cfg or FFInitConfig()
    system = build_system(window)
    rej = check_conditioning(window, system, cfg)
    if rej is not None:
        return rej
    sol = weighted_solve(system, cfg.gravity, cfg.gravity_refinements,
                         cfg.gravity_magnitude == "absorb_bias")
    if sol is None:
        return Rejection("solve_failed", "least squares returned non-finite values")
    return sol
