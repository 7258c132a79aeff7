"""Operations on the state: EKF update (with QR compression), clone augmentation, marginalisation,
delayed landmark initialisation with a chi-square test (OpenVINS StateHelper structure).
"""
from __future__ import annotations

import numpy as np
from numba import njit
from scipy.linalg.blas import dsyrk
from scipy.linalg.lapack import dgeqrf, dpotrf, dtrtrs
from scipy.special import gammaincinv

from runtime.msckf.measurement import givens_left_nullspace, projected_mahalanobis
from runtime.msckf.state import Clone, Landmark, State


def _chi2_quantile_95(dof: np.ndarray | int) -> np.ndarray:
    """95 % quantile of the chi-square distribution, 2 P^-1(dof / 2, 0.95) with P the regularised lower
    incomplete gamma function: scipy.stats.chi2.ppf's own formula, bit for bit, without importing
    scipy.stats (about 1 s at every command's start on a 2-core machine)."""
    return 2.0 * gammaincinv(np.asarray(dof, np.float64) / 2.0, 0.95)


_CHI2_95 = _chi2_quantile_95(np.arange(1, 2001))


def chi2_95(dof: int) -> float:
    """95% quantile of the chi-square distribution with dof degrees of freedom."""
    return float(_CHI2_95[dof - 1]) if dof <= _CHI2_95.size else float(_chi2_quantile_95(dof))


def chi2_accepts(d2: float, dof: int, multiplier: float) -> bool:
    """The filters' chi-square gate: d2 below multiplier times the 95 % quantile with dof degrees of freedom
    (False for NaN)."""
    return bool(d2 < multiplier * chi2_95(dof))


def compress(H: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """QR measurement compression: rows beyond the column count carry no information for isotropic noise.

    H = Q R, returned as (R, Q^T r): the triangular factor of the augmented [H | r] holds both (its last
    column is Q^T r over the first n rows), so Q is never formed."""
    m, n = H.shape
    if m <= n:
        return H, r
    Hr = np.empty((m, n + 1), order="F")    # LAPACK's layout: geqrf factors it in place
    Hr[:, :n] = H
    Hr[:, n] = r
    qr, _, _, info = dgeqrf(Hr, overwrite_a=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"QR compression failed (dgeqrf info {info})")
    return np.triu(qr[:n, :n]), qr[:n, n].copy()


_MIRROR_TILE = 32


@njit(cache=True, nogil=True)
def _mirror_lower_to_upper(P: np.ndarray) -> None:
    """P[i, j] = P[j, i] for j < i (in place), in square tiles so that the strided reads stay in cache."""
    n = P.shape[0]
    for bi in range(0, n, _MIRROR_TILE):
        ei = min(bi + _MIRROR_TILE, n)
        for bj in range(bi, n, _MIRROR_TILE):
            ej = min(bj + _MIRROR_TILE, n)
            for i in range(bi, ei):
                for j in range(max(bj, i + 1), ej):
                    P[i, j] = P[j, i]


def ekf_update(state: State, cols: np.ndarray, H: np.ndarray, r: np.ndarray, sigma: float) -> bool:
    """EKF update with measurement r = H dx[cols] + n, n ~ N(0, sigma^2 I). Returns False if S is not PD.

    With S = L L^T and W = L^-1 H P[cols, :], the covariance update P - W^T W is one symmetric rank-m
    update of one triangle (BLAS syrk, in place), mirrored to the other; dx = W^T L^-1 r."""
    if not state.P.flags.c_contiguous:
        state.P = np.ascontiguousarray(state.P)
    P = state.P
    m = H.shape[0]
    A = np.asfortranarray(H @ P[cols])     # m x n  (= H P[cols, :], P symmetric)
    S = A[:, cols] @ H.T
    S.flat[::m + 1] += sigma * sigma
    # LAPACK directly: the scipy.linalg wrappers' checks cost more than these small factorisations
    L, info = dpotrf(S, lower=1, clean=0, overwrite_a=1)
    if info != 0:
        return False
    W, info = dtrtrs(L, A, lower=1, overwrite_b=1)
    z, info_r = dtrtrs(L, np.asarray(r, np.float64), lower=1)
    if info != 0 or info_r != 0:
        return False
    dx = W.T @ z
    if not np.isfinite(dx).all():   # a NaN pivot passes OpenBLAS's potrf
        return False
    # P.T is P's memory in Fortran order: syrk's upper triangle there is the lower triangle of P
    out = dsyrk(-1.0, W, beta=1.0, c=P.T, trans=1, lower=0, overwrite_c=1)
    if not np.shares_memory(out, P):
        P[...] = out.T
    _mirror_lower_to_upper(P)
    state.apply_correction(dx)
    return True


def augment_clone(state: State, t_cam_ns: int, w_body: np.ndarray) -> Clone:
    """Clone the IMU pose (value and FEJ) at camera time t_cam_ns. With an estimated time offset the
    clone also depends on t_d through [w_body; v] (d pose / d t)."""
    n = state.size
    J = np.zeros((6, n))
    J[0:3, 0:3] = np.eye(3)
    J[3:6, 3:6] = np.eye(3)
    if state.idx_dt >= 0:
        J[0:3, state.idx_dt] = w_body
        J[3:6, state.idx_dt] = state.v
    cross = J @ state.P
    cov = cross @ J.T
    idx = state.add_variable(6, 0.5 * (cov + cov.T), cross)
    c = Clone(t_cam_ns, state.R.copy(), state.p.copy(), state.R.copy(), state.p.copy(), idx)
    state.clones[t_cam_ns] = c
    return c


def marginalize(state: State, clone_times: list[int], landmark_ids: list[int]) -> None:
    """Remove several clones and landmarks in one covariance copy."""
    blocks = []
    for t in clone_times:
        blocks.append((state.clones.pop(t).idx, 6))
    for fid in landmark_ids:
        blocks.append((state.slam.pop(fid).idx, 3))
    state.remove_variables(blocks)


def split_landmark_rows(Pcc: np.ndarray, Hx: np.ndarray, Hf: np.ndarray, r: np.ndarray, sigma: float,
                        chi2_multiplier: float) -> tuple | None:
    """The gate of a landmark's delayed initialisation (OpenVINS StateHelper::initialize): Givens rotations of
    Hf split its m >= 2 observations into an invertible part (3 rows) that defines the landmark and the rest.

    Pcc: the covariance of Hx's columns. The Mahalanobis distance of the 2m-3 projected rows is compared with
    the 95% chi-square quantile of all 2m rows, as OpenVINS does (a looser gate than the projected rows' own
    quantile). Returns (Hf1_inv, Hx1, r1, Hx2, r2), or None when the gate refuses or Hf1 is singular."""
    Hx2, r2, Hf1, Hx1, r1 = givens_left_nullspace(Hf.copy(), Hx.copy(), r.copy())
    if Hx2.shape[0] > 0:
        Pc = Pcc if Pcc.flags.c_contiguous else np.ascontiguousarray(Pcc)
        if not chi2_accepts(projected_mahalanobis(Pc, Hx2, r2, float(sigma)), r.shape[0], chi2_multiplier):
            return None
    try:
        Hf1_inv = np.linalg.inv(Hf1)
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(Hf1_inv)):
        return None
    return Hf1_inv, Hx1, r1, Hx2, r2


def add_landmarks(state: State, cols: np.ndarray, new: list[tuple], sigma: float) -> list[Landmark]:
    """Append landmarks defined by the invertible parts of their rows, in one covariance copy.

    new: [(fid, p_O, p_fej, Hf1_inv, Hx1, r1)] with p_fej None for the landmark's initial value. With
    G_i = Hf1_i^-1 Hx1_i over `cols`: value p_O + Hf1_i^-1 r1_i, cross-covariance -G_i P[cols, :], covariance
    G_i P_cc G_j^T between landmarks plus sigma^2 Hf1_i^-1 Hf1_i^-T on the diagonal blocks: the same joint
    covariance as adding them one after another."""
    if not new:
        return []
    G = np.vstack([F @ Hx1 for _, _, _, F, Hx1, _ in new])            # 3L x k
    cross = -(G @ state.P[cols])                                     # 3L x n  (P symmetric)
    cov = -(cross[:, cols] @ G.T)                                    # G P_cc G^T
    s2 = sigma * sigma
    for i, (_, _, _, F, _, _) in enumerate(new):
        cov[3 * i:3 * i + 3, 3 * i:3 * i + 3] += s2 * (F @ F.T)
    idx0 = state.add_variable(3 * len(new), 0.5 * (cov + cov.T), cross)
    out = []
    for i, (fid, p_O, p_fej, F, _, r1) in enumerate(new):
        p_new = p_O + F @ r1
        lm = Landmark(fid, p_new.copy(), (p_new if p_fej is None else p_fej).copy(), idx0 + 3 * i)
        state.slam[fid] = lm
        out.append(lm)
    return out


def initialize_landmark(state: State, fid: int, p_O: np.ndarray, cols: np.ndarray, Hx: np.ndarray,
                        Hf: np.ndarray, r: np.ndarray, sigma: float, chi2_multiplier: float,
                        deferred: list | None = None, p_fej: np.ndarray | None = None,
                        Pcc: np.ndarray | None = None) -> bool:
    """Delayed initialisation of one landmark from m >= 2 observations (OpenVINS StateHelper::initialize):
    `split_landmark_rows`, then `add_landmarks`.

    p_fej: the landmark's first estimate (the point Hf was evaluated at); None: its initial value. Pcc: the
    covariance of `cols` when the caller has it (None: taken from the state). The rows beyond the invertible
    part are then used in an ordinary update, or, with `deferred`, appended there as (Hx2, r2) over `cols`
    for one stacked update by the caller (for a fixed linearisation the order of independent updates does not
    change the posterior)."""
    if Pcc is None:
        Pcc = state.P[np.ix_(cols, cols)]
    split = split_landmark_rows(Pcc, Hx, Hf, r, sigma, chi2_multiplier)
    if split is None:
        return False
    Hf1_inv, Hx1, r1, Hx2, r2 = split
    add_landmarks(state, cols, [(fid, p_O, p_fej, Hf1_inv, Hx1, r1)], sigma)
    if Hx2.shape[0] > 0:
        if deferred is not None:
            deferred.append((Hx2, r2))
        else:
            H2, rr2 = compress(Hx2, r2)
            ekf_update(state, cols, H2, rr2, sigma)
    return True
