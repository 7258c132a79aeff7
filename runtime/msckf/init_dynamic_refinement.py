"""Maximum-likelihood refinement of the dynamic initializer's window, and the newest state's covariance.

Unknowns (Levenberg-Marquardt on the normal equations with the analytic Jacobian, runtime.msckf.normal_lm;
or with `mle_solver = "scipy-fd"` scipy least_squares with forward differences over the Jacobian's sparsity
pattern), in the gravity-aligned frame O: per keyframe [theta (local rotation error of R_OIk), p_OIk,
v_OIk], then shared bias corrections [dbg, dba], then the feature positions p_Of. Residuals: reprojection
errors (normalized coordinates scaled by f / sigma_px), preintegration residuals [r_R, r_v, r_p]
whitened by their covariance, bias priors, and a gauge prior on the first position and yaw.
Covariance: inverse Gauss-Newton information, marginal of the newest keyframe's [theta, p, v] and
the biases, inflated per block (OpenVINS init_dyn_inflation_*).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.optimize
import scipy.sparse

from runtime.geometry import so3_exp, so3_log
from runtime.geometry.so3 import skew, so3_right_jacobian, so3_right_jacobian_inv
from runtime.imu import Preintegration
from runtime.msckf.init_dynamic_config import DynamicInitConfig
from runtime.msckf.init_dynamic_sparse_jacobian import sparse_fd_jacobian
from runtime.msckf.normal_lm import levenberg_marquardt


@dataclass
class RefinedWindow:
    """Refined keyframe states in O and the newest one's covariance.

    Attributes:
        R_OI: (K, 3, 3) keyframe orientations.  p_OI: (K, 3) positions, m.  v_OI: (K, 3) velocities, m/s.
        bg: (3,) gyro bias, rad/s.  ba: (3,) accelerometer bias, m/s^2.
        cov: (15, 15) inflated covariance of the newest keyframe in ERROR_STATE_ORDER (init_common).
        rms_px: RMS reprojection error, px.  n_evaluations: residual evaluations of the solver.
        converged: the solver met an end test within its evaluations (True with the refinement disabled).
    """

    R_OI: np.ndarray
    p_OI: np.ndarray
    v_OI: np.ndarray
    bg: np.ndarray
    ba: np.ndarray
    cov: np.ndarray
    rms_px: float
    n_evaluations: int
    converged: bool


class WindowRefinement:
    """Nonlinear least squares over keyframe states, bias corrections and features.

    Args:
        obs: (N, 4) rows (keyframe k, feature n, x, y), normalized camera coordinates; every feature
            index 0..max(n) is observed.
        between: K-1 preintegrations between neighbouring keyframes (with covariances).
        g_O: (3,) gravitational acceleration in O, m/s^2.
        bg0, ba0: (3,) the biases ``between`` was integrated at (rad/s, m/s^2); the priors' centres.
        R_IC, p_IC: camera pose in the IMU frame (p_IC in m).
        focal_px: focal length, px (converts normalized residuals to pixels).
        cfg: sigma_px, bias prior sigmas, mle_max_iterations / mle_tolerance and inflation.
    """

    def __init__(
        self,
        obs: np.ndarray,
        between: list[Preintegration],
        g_O: np.ndarray,
        bg0: np.ndarray,
        ba0: np.ndarray,
        R_IC: np.ndarray,
        p_IC: np.ndarray,
        focal_px: float,
        cfg: DynamicInitConfig,
    ) -> None:
        self.cfg = cfg
        self.R_CI = R_IC.T
        self.p_CI = -R_IC.T @ p_IC
        self.focal_px = focal_px
        self.obs_k = obs[:, 0].astype(int)
        self.obs_f = obs[:, 1].astype(int)
        self.obs_xy = obs[:, 2:4]
        self.between = between
        self.g_O = g_O
        self.bg0, self.ba0 = bg0, ba0
        self.n_kf = len(between) + 1
        self.n_feat = int(self.obs_f.max()) + 1
        self.w_px = focal_px / cfg.sigma_px
        # whitening of each preintegration residual [r_R, r_v, r_p]
        self.sqrt_info = [np.linalg.inv(np.linalg.cholesky(p.cov + np.eye(9) * 1e-12)) for p in between]
        # linearisation point of the rotations and the gauge (set by run)
        self.R_hat = np.zeros((self.n_kf, 3, 3))
        self.p0_hat = np.zeros(3)

    def _unpack(self, x: np.ndarray) -> tuple[np.ndarray, ...]:
        """(R_OIk, p_OIk, v_OIk, dbg, dba, p_Of) from the parameter vector."""
        K = self.n_kf
        st = x[: 9 * K].reshape(K, 9)
        dbg = x[9 * K : 9 * K + 3]
        dba = x[9 * K + 3 : 9 * K + 6]
        feats = x[9 * K + 6 :].reshape(-1, 3)
        R = self.R_hat @ so3_exp(st[:, 0:3])
        return R, st[:, 3:6], st[:, 6:9], dbg, dba, feats

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """Whitened residual vector (dimensionless) at the parameters x (layout: module docstring)."""
        R, p, v, dbg, dba, feats = self._unpack(x)
        k, f = self.obs_k, self.obs_f
        p_I = np.einsum("nji,nj->ni", R[k], feats[f] - p[k])
        p_C = p_I @ self.R_CI.T + self.p_CI
        z = np.where(np.abs(p_C[:, 2]) > 1e-6, p_C[:, 2], 1e-6)
        r_proj = ((p_C[:, :2] / z[:, None]) - self.obs_xy) * self.w_px
        out = [r_proj.ravel()]
        g = self.g_O
        for j, pre in enumerate(self.between):
            dR, dv, dp = pre.corrected(dbg, dba)
            dt = pre.dt
            Rt = R[j].T
            r_R = so3_log(dR.T @ Rt @ R[j + 1])
            r_v = Rt @ (v[j + 1] - v[j] - g * dt) - dv
            r_p = Rt @ (p[j + 1] - p[j] - v[j] * dt - 0.5 * g * dt * dt) - dp
            out.append(self.sqrt_info[j] @ np.concatenate([r_R, r_v, r_p]))
        out.append(dbg / self.cfg.sigma_bg_prior)
        out.append(dba / self.cfg.sigma_ba_prior)
        # gauge: first position and yaw (rotation about O's z) stay where the linear solve put them
        out.append((p[0] - self.p0_hat) / 1e-4)
        out.append(np.array([(self.R_hat[0] @ x[0:3])[2] / 1e-4]))
        return np.concatenate(out)

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """Analytic Jacobian of :meth:`residuals` at x (rows: residuals, columns: parameters; dense, its
        non-zeros within :meth:`sparsity`).

        Rotations are perturbed on the right, R_k(theta + d) ~= R_k Exp(Jr(theta) d); the
        preintegration rotation residual Log(E) moves by Jr^-1(Log E) times the perturbation of E.
        """
        R, p, v, dbg, dba, feats = self._unpack(x)
        K, F = self.n_kf, self.n_feat
        Jr = so3_right_jacobian(x[: 9 * K].reshape(K, 9)[:, 0:3])
        Rt = np.swapaxes(R, 1, 2)
        rows, cols, vals = [], [], []

        # reprojections: d r / d p_C, then p_C = R_CI R_k^T (p_f - p_k) + p_CI
        k, f = self.obs_k, self.obs_f
        n_obs = k.size
        p_I = np.einsum("nij,nj->ni", Rt[k], feats[f] - p[k])
        p_C = p_I @ self.R_CI.T + self.p_CI
        clamped = np.abs(p_C[:, 2]) <= 1e-6
        z = np.where(clamped, 1e-6, p_C[:, 2])
        D = np.zeros((n_obs, 2, 3))
        D[:, 0, 0] = D[:, 1, 1] = 1.0 / z
        D[:, 0, 2] = np.where(clamped, 0.0, -p_C[:, 0] / z**2)
        D[:, 1, 2] = np.where(clamped, 0.0, -p_C[:, 1] / z**2)
        D *= self.w_px
        J_f = D @ (self.R_CI @ Rt[k])
        J_theta = D @ self.R_CI @ skew(p_I) @ Jr[k]
        vals.append(np.concatenate([J_theta, -J_f, J_f], axis=2).ravel())
        c = np.concatenate([9 * k[:, None] + np.arange(6), (9 * K + 6 + 3 * f)[:, None] + np.arange(3)],
                           axis=1)
        rows.append(np.repeat(2 * np.arange(n_obs)[:, None] + np.arange(2), 9, axis=1).ravel())
        cols.append(np.repeat(c[:, None, :], 2, axis=1).ravel())

        # preintegration pairs: raw 9 x 24 block over [state j, state j+1, dbg, dba], then whitened
        g = self.g_O
        block_cols = np.arange(24)
        block_cols[18:] = 9 * K + np.arange(6)
        for j, pre in enumerate(self.between):
            dR, _, _ = pre.corrected(dbg, dba)
            dt = pre.dt
            E = dR.T @ Rt[j] @ R[j + 1]
            Jri = so3_right_jacobian_inv(so3_log(E))
            u_v = v[j + 1] - v[j] - g * dt
            u_p = p[j + 1] - p[j] - v[j] * dt - 0.5 * g * dt * dt
            B = np.zeros((9, 24))
            B[0:3, 0:3] = -Jri @ Rt[j + 1] @ R[j] @ Jr[j]
            B[0:3, 9:12] = Jri @ Jr[j + 1]
            B[0:3, 18:21] = -Jri @ E.T @ so3_right_jacobian(pre.J_R_bg @ dbg) @ pre.J_R_bg
            B[3:6, 0:3] = skew(Rt[j] @ u_v) @ Jr[j]
            B[3:6, 6:9] = -Rt[j]
            B[3:6, 15:18] = Rt[j]
            B[3:6, 18:21] = -pre.J_v_bg
            B[3:6, 21:24] = -pre.J_v_ba
            B[6:9, 0:3] = skew(Rt[j] @ u_p) @ Jr[j]
            B[6:9, 3:6] = -Rt[j]
            B[6:9, 6:9] = -Rt[j] * dt
            B[6:9, 12:15] = Rt[j]
            B[6:9, 18:21] = -pre.J_p_bg
            B[6:9, 21:24] = -pre.J_p_ba
            base = 2 * n_obs + 9 * j
            vals.append((self.sqrt_info[j] @ B).ravel())
            rows.append(np.repeat(base + np.arange(9), 24))
            block_cols[:18] = 9 * j + np.arange(18)
            cols.append(np.tile(block_cols, 9))

        # bias priors and the gauge (first position and yaw)
        base = 2 * n_obs + 9 * (K - 1)
        rows.append(np.r_[base + np.arange(9), np.full(3, base + 9)])
        cols.append(np.r_[9 * K + np.arange(6), 3, 4, 5, 0, 1, 2])
        vals.append(np.r_[np.full(3, 1.0 / self.cfg.sigma_bg_prior),
                          np.full(3, 1.0 / self.cfg.sigma_ba_prior), np.full(3, 1e4),
                          self.R_hat[0][2] / 1e-4])
        J = np.zeros((2 * n_obs + 9 * (K - 1) + 10, 9 * K + 6 + 3 * F))
        J[np.concatenate(rows), np.concatenate(cols)] = np.concatenate(vals)    # no entry is set twice
        return J

    def sparsity(self) -> scipy.sparse.lil_matrix:
        """(residuals, parameters) 0/1 pattern of the Jacobian of :meth:`residuals`."""
        K, F = self.n_kf, self.n_feat
        n_obs = self.obs_k.size
        n_res = 2 * n_obs + 9 * (K - 1) + 6 + 4
        n_par = 9 * K + 6 + 3 * F
        S = scipy.sparse.lil_matrix((n_res, n_par), dtype=int)
        for i in range(n_obs):
            kk, ff = self.obs_k[i], self.obs_f[i]
            for r in (2 * i, 2 * i + 1):
                S[r, 9 * kk : 9 * kk + 6] = 1
                S[r, 9 * K + 6 + 3 * ff : 9 * K + 9 + 3 * ff] = 1
        base = 2 * n_obs
        for j in range(K - 1):
            rows = slice(base + 9 * j, base + 9 * j + 9)
            S[rows, 9 * j : 9 * j + 18] = 1
            S[rows, 9 * K : 9 * K + 6] = 1
        base += 9 * (K - 1)
        S[base : base + 6, 9 * K : 9 * K + 6] = 1
        S[base + 6 : base + 9, 3:6] = 1
        S[base + 9, 0:3] = 1
        return S

    def run(self, R_k: np.ndarray, p_k: np.ndarray, v_k: np.ndarray, p_f: np.ndarray) -> RefinedWindow | None:
        """Refine from the keyframe states R_OIk (K, 3, 3), p_OIk, v_OIk (K, 3) and features p_Of (F, 3).

        Returns None when the solution, its information matrix or the covariance is not usable.
        """
        K = self.n_kf
        self.R_hat = R_k.copy()
        self.p0_hat = p_k[0].copy()
        x0 = np.concatenate(
            [np.concatenate([np.zeros((K, 3)), p_k, v_k], axis=1).ravel(), np.zeros(6), p_f.ravel()]
        )
        analytic = self.cfg.mle_solver == "lm"
        nfev = 0
        x = x0
        converged = True
        if self.cfg.mle_max_iterations > 0:
            if analytic:
                sol = levenberg_marquardt(self.residuals, self.jacobian, x0, self.cfg.mle_max_iterations,
                                          self.cfg.mle_tolerance, self.cfg.mle_tolerance)
            else:
                sol = scipy.optimize.least_squares(
                    self.residuals, x0, method="trf", jac_sparsity=self.sparsity(),
                    max_nfev=self.cfg.mle_max_iterations, x_scale="jac",
                    ftol=self.cfg.mle_tolerance, xtol=self.cfg.mle_tolerance,
                )
            x, nfev = sol.x, int(sol.nfev)
            # scipy's status <= 0: the evaluations ran out (0) or a callback stopped it (-2)
            converged = bool(sol.converged) if analytic else bool(sol.success)
            if not np.all(np.isfinite(x)):
                return None
        # Jacobian at the solution, re-centred so theta is a local perturbation of the final rotations
        R, p, v, dbg, dba, _ = self._unpack(x)
        self.R_hat = R
        xc = x.copy()
        xc[: 9 * K].reshape(K, 9)[:, 0:3] = 0.0
        if analytic:
            J = self.jacobian(xc)
        else:
            J = sparse_fd_jacobian(self.residuals, xc, self.sparsity()).toarray()
        r = self.residuals(xc)
        n_proj = 2 * self.obs_k.size
        rms_px = float(np.sqrt(np.mean((r[:n_proj] / self.w_px * self.focal_px) ** 2)))
        cov = newest_state_covariance(J.T @ J, K, self.cfg.inflation)
        if cov is None:
            return None
        return RefinedWindow(R, p, v, self.bg0 + dbg, self.ba0 + dba, cov, rms_px, nfev, converged)


def newest_state_covariance(
    info: np.ndarray, n_kf: int, inflation: tuple[float, float, float, float, float]
) -> np.ndarray | None:
    """(15, 15) covariance of the newest keyframe's [theta, p, v] and [bg, ba], variance-inflated per block.

    Args:
        info: (n, n) Gauss-Newton information of the refinement's parameters (layout: module docstring).
        n_kf: number of keyframes K.
        inflation: variance factors per ERROR_STATE_ORDER block (theta, p, v, bg, ba).

    Returns None when the information is singular or the covariance is not finite and positive.
    """
    try:
        cov_all = np.linalg.inv(info + np.eye(info.shape[0]) * 1e-12 * np.trace(info) / info.shape[0])
    except np.linalg.LinAlgError:
        return None  # singular information: reported as a failed refinement
    idx = np.r_[9 * (n_kf - 1) : 9 * n_kf, 9 * n_kf : 9 * n_kf + 6]
    cov = cov_all[np.ix_(idx, idx)]
    infl = np.sqrt(np.repeat(inflation, 3))
    cov = infl[:, None] * cov * infl[None, :]
    cov = 0.5 * (cov + cov.T)
    if not (np.all(np.isfinite(cov)) and np.all(np.diag(cov) > 0)):
        return None
    return cov
