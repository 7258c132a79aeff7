"""Huber refinement of an accepted linear solution (paper Sec. IV-C, eq. 8).

Parameters theta = [eta, v0 (3), dgamma (2), dbg (3), ba (3)]:
  s = eps + softplus(eta);  g = g0 Exp(N dgamma) g_hat with N^T g_hat = 0;
  R_I0Ii(theta) = R_I0Ii Exp(J_R_bg dbg);  dp_i(theta) = dp_i + J_p_bg dbg + J_p_ba (ba - ba_bar).
Residuals: normalized reprojection errors of the inlier points / sigma_u, priors dbg / sigma_g,
(ba - ba_prior) / sigma_a, log(s / s_lin) / sigma_s; component-wise Huber loss with unit threshold.
ba_prior is the preintegration's bias (zero at start-up, as in the paper) plus the bias along
gravity implied by the linear stage when FFInitConfig.gravity_magnitude == "absorb_bias".
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from runtime.ffinit.config import FFInitConfig
from runtime.ffinit.linear import LinearSolution, _tangent_basis
from runtime.ffinit.window import InitWindow
from runtime.geometry import so3_exp


@dataclass
class Refined:
    """Refined start-up state in I0 and the parameter covariance (12 x 12, theta order)."""

    scale: float
    v0: np.ndarray
    g: np.ndarray
    dbg: np.ndarray
    ba: np.ndarray
    cov_theta: np.ndarray
    cost: float
    success: bool
    N: np.ndarray
    cov_observed: np.ndarray | None = None
    """Covariance (12 x 12) from what the window measures: the image rows of the robust cost's
    Gauss-Newton Jacobian (scipy's: rows on Huber's linear branch drop out), the gyro-bias prior and an
    accelerometer-bias prior of FFInitConfig.accel_bias_sigma (0: the bias held fixed); without the
    log(s / s_lin) pseudo-prior, which only regularises towards the linear stage."""


def _softplus(x: float) -> float:
    return float(np.logaddexp(0.0, x))


def _inv_softplus(y: float) -> float:
    return float(y + np.log(-np.expm1(-y))) if y < 30 else float(y)


class _Problem:
    def __init__(self, window: InitWindow, inliers_per_image: list[np.ndarray], lin: LinearSolution,
                 cfg: FFInitConfig) -> None:
        self.w = window
        self.cfg = cfg
        self.g_hat = lin.g / np.linalg.norm(lin.g)
        self.N = _tangent_basis(self.g_hat)
        self.s_lin = lin.scale
        # the accelerometer-bias prior is centred on the current estimate: the preintegration bias
        # plus, with gravity_magnitude == "absorb_bias", the bias along gravity the linear stage implied
        self.ba_prior = window.ba + lin.ba
        self.pts = []  # per image i>0: (points_C0 (K,3), z (K,2))
        for i in range(1, window.num_images):
            m = inliers_per_image[i]
            obs = window.images[i]
            self.pts.append((i, obs.points_C0[m], obs.z[m]))

    def unpack(self, th: np.ndarray):
        s = self.cfg.softplus_eps + _softplus(th[0])
        v0 = th[1:4]
        g = self.cfg.gravity * so3_exp(self.N @ th[4:6]) @ self.g_hat
        return s, v0, g, th[6:9], th[9:12]

    def residuals(self, th: np.ndarray) -> np.ndarray:
        w, cfg = self.w, self.cfg
        s, v0, g, dbg, ba = self.unpack(th)
        dba = ba - w.ba
        R_CI = w.R_IC.T
        out = []
        for i, P, z in self.pts:
            R_I0Ii = w.R_I0Ii[i] @ so3_exp(w.J_R_bg[i] @ dbg)
            dp = w.dp[i] + w.J_p_bg[i] @ dbg + w.J_p_ba[i] @ dba
            dt = w.dt[i]
            p_I0Ii = dt * v0 - 0.5 * dt * dt * g + dp
            x_I0 = s * P @ w.R_IC.T + w.p_IC - p_I0Ii
            y = (x_I0 @ R_I0Ii) @ R_CI.T - R_CI @ w.p_IC  # R_CI [R_IiI0 x - p_IC]
            zc = np.maximum(y[:, 2], 1e-6)
            out.append(((y[:, :2] / zc[:, None] - z) / cfg.sigma_u).ravel())
        out.append(dbg / cfg.sigma_bg)
        out.append((ba - self.ba_prior) / cfg.sigma_ba)
        out.append(np.array([np.log(s / self.s_lin) / cfg.sigma_scale]))
        return np.concatenate(out)


def refine(window: InitWindow, lin: LinearSolution, inliers_per_image: list[np.ndarray],
           cfg: FFInitConfig | None = None, dbg0: np.ndarray | None = None) -> Refined:
    """Minimise eq. (8) from the linear solution (and an optional gyro-bias change dbg0)."""
    cfg = cfg or FFInitConfig()
    prob = _Problem(window, inliers_per_image, lin, cfg)
    th0 = np.zeros(12)
    th0[0] = _inv_softplus(max(lin.scale - cfg.softplus_eps, 1e-9))
    th0[1:4] = lin.v0
    if dbg0 is not None:
        th0[6:9] = dbg0
    th0[9:12] = window.ba + lin.ba
    res = least_squares(prob.residuals, th0, loss="huber", f_scale=cfg.huber_threshold,
                        max_nfev=cfg.refine_max_iterations * 13, x_scale="jac")
    s, v0, g, dbg, ba = prob.unpack(res.x)
    J = res.jac
    try:
        cov = np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        cov = np.full((12, 12), np.nan)
    return Refined(s, v0, g, dbg, ba, cov, float(res.cost), bool(res.success), prob.N,
                   observed_covariance(J[:-7], cfg))


def observed_covariance(J_images: np.ndarray, cfg: FFInitConfig) -> np.ndarray:
    """(J^T J + priors)^-1 of the image rows with the gyro-bias prior (sigma_bg) and an accelerometer-bias
    prior of accel_bias_sigma (0: the bias is held fixed, its rows and columns are zero); NaN when
    singular (no scale prior: the window alone must fix s)."""
    H = J_images.T @ J_images
    H[6:9, 6:9] += np.eye(3) / cfg.sigma_bg ** 2
    n = 12
    if cfg.accel_bias_sigma > 0:
        H[9:12, 9:12] += np.eye(3) / cfg.accel_bias_sigma ** 2
    else:
        n = 9
    cov = np.zeros((12, 12))
    try:
        cov[:n, :n] = np.linalg.inv(H[:n, :n])
    except np.linalg.LinAlgError:
        return np.full((12, 12), np.nan)
    return cov if np.all(np.isfinite(cov)) and cov[0, 0] >= 0 else np.full((12, 12), np.nan)
