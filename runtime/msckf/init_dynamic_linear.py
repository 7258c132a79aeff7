"""The dynamic initializer's linear solve: features, velocity and gravity under |g| = g0.

Following Dong-Si & Mourikis (ICRA 2012, Eq. 14) as OpenVINS' ``DynamicInitializer``: with rotations
from gyro preintegration and I0 the first keyframe's IMU frame, keyframe k sits at
``p_k = v0 t_k + g t_k^2 / 2 + dp_0k`` (all in I0), so each normalized observation (x, y) of the
feature p_f gives two equations linear in (p_f, v0, g):
``[1 0 -x; 0 1 -y] (R_CI R_0k^T (p_f - p_k) + p_CI) = 0``.
Features and v0 are eliminated; g minimises the reduced quadratic on the sphere |g| = g0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.optimize

from runtime.msckf.init_common import rotation_from_up


@dataclass
class LinearSolution:
    """Result of the gravity-constrained linear solve, all in the first keyframe's IMU frame I0.

    Attributes:
        v_I0: (3,) velocity of I0, m/s.  g_I0: (3,) gravitational acceleration in I0, |g| = g0.
        p_f: (F, 3) feature positions in I0, m.  cost: residual sum of squares (normalized units).
        condition: eigenvalue ratio of the reduced velocity block after eliminating the features.
        n_good: features with depth information (the others have NaN positions).
    """

    v_I0: np.ndarray
    g_I0: np.ndarray
    p_f: np.ndarray
    cost: float
    condition: float
    n_good: int


def min_quadratic_on_sphere(M: np.ndarray, m: np.ndarray, radius: float) -> np.ndarray:
    """argmin over |g| = radius of g^T M g - 2 m^T g (M symmetric PSD 3x3); (3,) in m's units.

    The stationarity condition (M - lam I) g = m; the global minimum has lam below M's smallest
    eigenvalue, where |g(lam)| grows monotonically, so lam is found by a bracketed root search.
    """
    e, U = np.linalg.eigh(0.5 * (M + M.T))
    mp = U.T @ m
    norm_m = float(np.linalg.norm(mp))
    if norm_m < 1e-300:
        return radius * U[:, 0]
    e0 = float(e[0])

    def excess(lam: float) -> float:
        return float(np.sum((mp / (e - lam)) ** 2) - radius * radius)

    lo = e0 - norm_m / radius - 1e-12 * max(1.0, abs(e0))
    hi = e0 - 1e-15 * max(1.0, abs(e0), norm_m / radius)
    if excess(hi) <= 0.0:
        # hard case: the component along the smallest eigenvector is (numerically) zero
        g = np.zeros(3)
        g[1:] = mp[1:] / (e[1:] - e0)
        rest = radius * radius - float(g @ g)
        g[0] = np.sqrt(max(rest, 0.0)) * (1.0 if mp[0] >= 0 else -1.0)
        return U @ g
    while excess(lo) > 0.0:
        lo = e0 - 2.0 * (e0 - lo)
    lam = scipy.optimize.brentq(excess, lo, hi, xtol=1e-14 * max(1.0, abs(e0)), maxiter=200)
    return U @ (mp / (e - lam))


def solve_linear(
    obs: np.ndarray,
    n_feat: int,
    R_0k: np.ndarray,
    dt_0k: np.ndarray,
    dp_0k: np.ndarray,
    R_IC: np.ndarray,
    p_IC: np.ndarray,
    gravity_mag: float,
    min_features: int,
    max_feature_condition: float,
) -> LinearSolution:
    """Features, v0 and g (|g| = gravity_mag) in I0 from observations and preintegration.

    Args:
        obs: (N, 4) rows (keyframe k, feature n < n_feat, x, y), normalized camera coordinates.
        R_0k: (K, 3, 3) R_{I0 Ik}.  dt_0k: (K,) s since keyframe 0.  dp_0k: (K, 3) gravity-free
            displacement from I0 in I0, m (see init_dynamic_preintegration.KeyframeImu).
        R_IC, p_IC: camera pose in the IMU frame (x_I = R_IC x_C + p_IC), p_IC in m.
        gravity_mag: g0, m/s^2.
        min_features: fewer features with depth information give a solution with infinite cost.
        max_feature_condition: a feature whose 3x3 normal block has a larger eigenvalue ratio has no
            depth information: it is left out and gets a NaN position.

    Each feature is eliminated from the normal equations by its own 3x3 block (a Schur complement),
    then v0. ``condition`` is the eigenvalue ratio of the reduced velocity block (inf if too few
    features or singular; then v0 = g = 0).
    """
    R_CI = R_IC.T
    p_CI = -R_IC.T @ p_IC
    k = obs[:, 0].astype(int)
    f = obs[:, 1].astype(int)
    n_obs = obs.shape[0]
    H = np.zeros((n_obs, 2, 3))
    H[:, 0, 0] = 1.0
    H[:, 1, 1] = 1.0
    H[:, 0, 2] = -obs[:, 2]
    H[:, 1, 2] = -obs[:, 3]
    J_f = H @ (R_CI[None] @ np.transpose(R_0k[k], (0, 2, 1)))  # (n, 2, 3): H R_CI R_0k^T
    dt = dt_0k[k][:, None, None]
    J_z = np.concatenate([-J_f * dt, -0.5 * J_f * dt**2], axis=2)  # (n, 2, 6): [v0, g]
    rhs = np.einsum("nij,nj->ni", J_f, dp_0k[k]) - H @ p_CI
    # per-feature normal blocks
    F_ff = np.zeros((n_feat, 3, 3))
    F_fz = np.zeros((n_feat, 3, 6))
    b_f = np.zeros((n_feat, 3))
    np.add.at(F_ff, f, np.einsum("nri,nrj->nij", J_f, J_f))
    np.add.at(F_fz, f, np.einsum("nri,nrj->nij", J_f, J_z))
    np.add.at(b_f, f, np.einsum("nri,nr->ni", J_f, rhs))
    ev = np.linalg.eigvalsh(F_ff)
    good = ev[:, 0] > ev[:, 2] / max_feature_condition
    n_good = int(good.sum())
    p_f = np.full((n_feat, 3), np.nan)
    if n_good < min_features:
        return LinearSolution(np.zeros(3), np.zeros(3), p_f, float("inf"), float("inf"), n_good)
    keep_obs = good[f]
    Z = np.einsum("nri,nrj->ij", J_z[keep_obs], J_z[keep_obs])
    b_z = np.einsum("nri,nr->i", J_z[keep_obs], rhs[keep_obs])
    F_inv = np.linalg.inv(F_ff[good])
    S = Z - np.einsum("fia,fij,fjb->ab", F_fz[good], F_inv, F_fz[good])
    sv = b_z - np.einsum("fia,fij,fj->a", F_fz[good], F_inv, b_f[good])
    S_vv, S_vg, S_gg = S[:3, :3], S[:3, 3:], S[3:, 3:]
    e_v = np.linalg.eigvalsh(S_vv)
    condition = float(e_v[2] / e_v[0]) if e_v[0] > 0 else float("inf")
    if not np.isfinite(condition):
        return LinearSolution(np.zeros(3), np.zeros(3), p_f, float("inf"), condition, n_good)
    S_vv_inv = np.linalg.inv(S_vv)
    M = S_gg - S_vg.T @ S_vv_inv @ S_vg
    m = sv[3:] - S_vg.T @ S_vv_inv @ sv[:3]
    g = min_quadratic_on_sphere(M, m, gravity_mag)
    v0 = S_vv_inv @ (sv[:3] - S_vg @ g)
    z = np.concatenate([v0, g])
    p_f[good] = np.einsum("fij,fj->fi", F_inv, b_f[good] - F_fz[good] @ z)
    r = np.einsum("nij,nj->ni", J_f, p_f[f]) + J_z @ z - rhs
    cost = float(np.sum(r[keep_obs] ** 2))
    return LinearSolution(v_I0=v0, g_I0=g, p_f=p_f, cost=cost, condition=condition, n_good=n_good)


def states_in_gravity_frame(
    lin: LinearSolution, R_0k: np.ndarray, dt_0k: np.ndarray, dp_0k: np.ndarray, dv_0k: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Keyframe states and features in the gravity-aligned frame O (origin at I0, z up, yaw by Gram-Schmidt).

    Args:
        lin: the linear solution (in I0); its feature positions must be finite.
        R_0k, dt_0k, dp_0k, dv_0k: keyframe preintegration from I0 (init_dynamic_preintegration.KeyframeImu).

    Returns:
        R_OIk (K, 3, 3), p_OIk (K, 3) m, v_OIk (K, 3) m/s and the features p_Of (F, 3) m.
    """
    R_OI0 = rotation_from_up(-lin.g_I0)
    R_k = R_OI0 @ R_0k
    p_k = np.einsum(
        "ij,kj->ki", R_OI0, lin.v_I0 * dt_0k[:, None] + 0.5 * lin.g_I0 * dt_0k[:, None] ** 2 + dp_0k
    )
    v_k = np.einsum("ij,kj->ki", R_OI0, lin.v_I0 + lin.g_I0 * dt_0k[:, None] + dv_0k)
    p_f = lin.p_f @ R_OI0.T
    return R_k, p_k, v_k, p_f


def in_front_of_first_camera(p_f: np.ndarray, R_IC: np.ndarray, p_IC: np.ndarray) -> tuple[np.ndarray, float]:
    """Which features lie in front of the first keyframe's camera C0.

    Args:
        p_f: (F, 3) feature positions in I0, m (NaN rows: no position).
        R_IC, p_IC: camera pose in the IMU frame (p_IC in m).

    Returns:
        (F,) mask of the finite features with positive depth along C0's optical axis, and the
        fraction of the finite features that have it.
    """
    usable = np.isfinite(p_f[:, 0])
    in_front = (p_f[usable] - p_IC) @ R_IC[:, 2] > 0
    fraction = float(np.mean(in_front))
    usable[usable] = in_front
    return usable, fraction
