"""IMU preintegration on the manifold (Forster et al., T-RO 2017) with bias Jacobians.

Between IMU frames I0 (time t0) and I1 (time t1) with biases fixed at (bg, ba):
  dR = R_{I0 I1},
  dv = R_{I0 W} (v1 - v0 - g_W dt),                 (gravity-free velocity change, in I0)
  dp = R_{I0 W} (p1 - p0 - v0 dt - g_W dt^2 / 2),   (gravity-free displacement, in I0)
with g_W = (0, 0, -g0) the gravitational acceleration. A bias change (dbg, dba) is applied to
first order: dR Exp(J_R_bg dbg), dv + J_v_bg dbg + J_v_ba dba, dp + J_p_bg dbg + J_p_ba dba.

Discretisation: the measurements are linear between samples (the ends are interpolated onto t0
and t1); each interval uses the mean of its two nodes, the rotation increment Exp(w dt) and the
mid-interval rotation for the specific force (second order). The bias Jacobians and the 9x9
covariance (error order [dphi, dv, dp], noisy = nominal Exp(dphi), + dv, + dp) are the exact
linearisations of this scheme, the noise being white with the given continuous densities.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from runtime.errors import EstimatorError
from runtime.geometry.so3 import so3_exp
from runtime.imu.kernels import nb_preintegrate
from runtime.imu.samples import imu_nodes


@dataclass(frozen=True)
class Preintegration:
    """Preintegrated IMU terms from t0_ns to t1_ns at the biases (bg, ba).

    Attributes:
        t0_ns, t1_ns: the interval, int64 ns.
        dt: t1 - t0 in seconds.
        dR: (3, 3) R_{I0 I1}.
        dv: (3,) gravity-free velocity change in I0, m/s.
        dp: (3,) gravity-free displacement in I0, m.
        cov: (9, 9) covariance of [dphi, dv, dp] or None when no noise densities were given.
        J_R_bg, J_v_bg, J_v_ba, J_p_bg, J_p_ba: (3, 3) first-order bias Jacobians.
        bg, ba: (3,) the biases the terms were integrated at (rad/s, m/s^2).
        n_intervals: number of integration intervals.
    """

    t0_ns: int
    t1_ns: int
    dt: float
    dR: np.ndarray
    dv: np.ndarray
    dp: np.ndarray
    cov: np.ndarray | None
    J_R_bg: np.ndarray
    J_v_bg: np.ndarray
    J_v_ba: np.ndarray
    J_p_bg: np.ndarray
    J_p_ba: np.ndarray
    bg: np.ndarray
    ba: np.ndarray
    n_intervals: int

    def corrected(self, dbg: np.ndarray, dba: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(dR, dv, dp) for the biases (bg + dbg, ba + dba), to first order in the bias change."""
        dbg = _vec3(dbg, "dbg")
        dba = _vec3(dba, "dba")
        dR = self.dR @ so3_exp(self.J_R_bg @ dbg)
        dv = self.dv + self.J_v_bg @ dbg + self.J_v_ba @ dba
        dp = self.dp + self.J_p_bg @ dbg + self.J_p_ba @ dba
        return dR, dv, dp

    def predict(self, R_WI0: np.ndarray, p_WI0: np.ndarray, v_WI0: np.ndarray,
                g0: float = 9.81) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(R_WI1, p_WI1, v_WI1) of the end state, given the start state in a z-up world W."""
        g_W = np.array([0.0, 0.0, -float(g0)])
        R0 = np.asarray(R_WI0, dtype=np.float64)
        p0 = _vec3(p_WI0, "p_WI0")
        v0 = _vec3(v_WI0, "v_WI0")
        dt = self.dt
        return (R0 @ self.dR, p0 + v0 * dt + 0.5 * g_W * dt * dt + R0 @ self.dp, v0 + g_W * dt + R0 @ self.dv)


def _vec3(x: object, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise EstimatorError(f"{name} must be a finite (3,) vector, got {a!r}")
    return a


class Preintegrator:
    """Preintegrates IMU samples over arbitrary intervals at fixed biases.

    Args:
        bg: (3,) gyroscope bias, rad/s, subtracted from the measurements.
        ba: (3,) accelerometer bias, m/s^2.
        gyro_noise_density: rad/s/sqrt(Hz); with accel_noise_density enables the covariance.
        accel_noise_density: m/s^2/sqrt(Hz).
    """

    def __init__(self, bg: np.ndarray, ba: np.ndarray, gyro_noise_density: float | None = None,
                 accel_noise_density: float | None = None) -> None:
        self.bg = _vec3(bg, "bg")
        self.ba = _vec3(ba, "ba")
        if (gyro_noise_density is None) != (accel_noise_density is None):
            raise EstimatorError("give both gyro_noise_density and accel_noise_density, or neither")
        for name, val in (("gyro_noise_density", gyro_noise_density),
                          ("accel_noise_density", accel_noise_density)):
            if val is not None and not (np.isfinite(val) and val >= 0.0):
                raise EstimatorError(f"{name} must be finite and >= 0, got {val}")
        self.gyro_noise_density = gyro_noise_density
        self.accel_noise_density = accel_noise_density

    def integrate(self, t_ns: np.ndarray, gyro: np.ndarray, accel: np.ndarray, t0_ns: int,
                  t1_ns: int) -> Preintegration:
        """Preintegrate from t0_ns to t1_ns (need not be sample times; inside the samples' span).

        t_ns (M,) int64 strictly increasing, gyro (M, 3) rad/s, accel (M, 3) m/s^2 in the IMU frame.
        Raises DataError on malformed samples or an interval they do not cover.
        """
        return self.integrate_many(t_ns, gyro, accel, t0_ns, np.array([t1_ns], dtype=np.int64))[0]

    def integrate_many(self, t_ns: np.ndarray, gyro: np.ndarray, accel: np.ndarray, t0_ns: int,
                       t_ends_ns: np.ndarray) -> list[Preintegration]:
        """Preintegrations from t0_ns to each of t_ends_ns (int64 ns, each >= t0), in one pass.

        Equivalent to calling `integrate` for each end (up to the O(dt^2) effect of the extra
        interpolated nodes at the other ends), at the cost of one integration to the last end.
        """
        ends = np.asarray(t_ends_ns).reshape(-1)
        dts, g_nodes, a_nodes, end_nodes = imu_nodes(t_ns, gyro, accel, t0_ns, ends)
        with_cov = self.gyro_noise_density is not None
        var_g = float(self.gyro_noise_density or 0.0) ** 2
        var_a = float(self.accel_noise_density or 0.0) ** 2
        dR, dv, dp, cov, J_R_bg, J_v_bg, J_v_ba, J_p_bg, J_p_ba = nb_preintegrate(
            dts, g_nodes, a_nodes, self.bg, self.ba, var_g, var_a, with_cov, end_nodes)
        return [Preintegration(
            t0_ns=int(t0_ns), t1_ns=int(t1), dt=(int(t1) - int(t0_ns)) * 1e-9, dR=dR[e], dv=dv[e], dp=dp[e],
            cov=cov[e] if with_cov else None, J_R_bg=J_R_bg[e], J_v_bg=J_v_bg[e], J_v_ba=J_v_ba[e],
            J_p_bg=J_p_bg[e], J_p_ba=J_p_ba[e], bg=self.bg.copy(), ba=self.ba.copy(),
            n_intervals=int(end_nodes[e])) for e, t1 in enumerate(ends)]
