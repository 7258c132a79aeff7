"""From the refined start-up solution (in I0) to a filter state at the last image, in a
gravity-aligned world O (z up, origin at I0, yaw of I0 kept), with floored covariance."""
from __future__ import annotations

import numpy as np

from runtime.ffinit.refine import Refined
from runtime.ffinit.window import InitWindow
from runtime.geometry import so3_exp
from runtime.msckf.init_common import InitResult

#: Covariance floors (1 sigma) of [theta, p, v, bg, ba] written into the filter (rad, m, m/s, rad/s, m/s^2).
COV_FLOORS = (0.017, 0.05, 0.05, 0.02, 0.02)


def gravity_alignment(g_I0: np.ndarray) -> np.ndarray:
    """R_OI0: the smallest rotation taking the 'up' vector g (expressed in I0) to +z of O."""
    a = g_I0 / np.linalg.norm(g_I0)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(a, z)
    s = np.linalg.norm(axis)
    c = float(a @ z)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    return so3_exp(axis / s * np.arctan2(s, c))


def state_at_last_image(window: InitWindow, ref: Refined, t_imu_ns: int) -> InitResult:
    """The filter state at the window's last image (IMU clock `t_imu_ns`)."""
    n = window.num_images - 1
    dba = ref.ba - window.ba
    R_I0In = window.R_I0Ii[n] @ so3_exp(window.J_R_bg[n] @ ref.dbg)
    dv = window.dv[n] + window.J_v_bg[n] @ ref.dbg + window.J_v_ba[n] @ dba
    dp = window.dp[n] + window.J_p_bg[n] @ ref.dbg + window.J_p_ba[n] @ dba
    dt = window.dt[n]
    p_I0In = dt * ref.v0 - 0.5 * dt * dt * ref.g + dp
    v_In_I0 = ref.v0 - ref.g * dt + dv
    R_OI0 = gravity_alignment(ref.g)
    var = np.concatenate([np.full(3, COV_FLOORS[0] ** 2), np.full(3, COV_FLOORS[1] ** 2),
                          np.full(3, COV_FLOORS[2] ** 2), np.full(3, COV_FLOORS[3] ** 2),
                          np.full(3, COV_FLOORS[4] ** 2)])
    est = np.diag(ref.cov_theta)
    if np.all(np.isfinite(est)):
        var[6:9] = np.maximum(var[6:9], est[1:4])
        var[9:12] = np.maximum(var[9:12], est[6:9])
        var[12:15] = np.maximum(var[12:15], est[9:12])
    return InitResult(
        t_ns=int(t_imu_ns), R_OI=R_OI0 @ R_I0In, p_OI=R_OI0 @ p_I0In, v_OI=R_OI0 @ v_In_I0,
        bg=window.bg + ref.dbg, ba=ref.ba.copy(), cov=np.diag(var), source="feedforward",
        info={"scale": ref.scale, "refine_cost": ref.cost, "refine_success": ref.success,
              "scale_rel_std": scale_relative_std(ref)})


def scale_relative_std(ref: Refined, observed: bool = False) -> float:
    """sigma(s) / s of the refined metric scale from the refinement's covariance (theta[0] is the
    softplus pre-image of s, so ds/dtheta0 = sigmoid(theta0) = 1 - exp(-s)); inf when not finite.
    observed: from Refined.cov_observed (the window's own information) instead of cov_theta."""
    cov = ref.cov_observed if observed else ref.cov_theta
    var = float(cov[0, 0]) if cov is not None and cov.size else float("nan")
    if not (np.isfinite(var) and var >= 0 and ref.scale > 0):
        return float("inf")
    return float(np.sqrt(var) * -np.expm1(-ref.scale) / ref.scale)
