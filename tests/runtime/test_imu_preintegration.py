"""IMU preintegration against closed forms, analytic motion, finite differences and Monte Carlo."""
from __future__ import annotations

import numpy as np
import pytest

from runtime.errors import DataError, EstimatorError
from runtime.geometry import skew, so3_exp, so3_log
from runtime.imu import Preintegrator

G0 = 9.81
EPOCH_NS = 1_403_636_579_758_555_392  # an EuRoC-like epoch, to exercise int64 stamps


def rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


class SineMotion:
    """Analytic body motion: R_WI = Rz(yaw) Ry(pitch) Rx(roll), sinusoidal position, z-up world."""

    def angles(self, t):
        yaw = 0.8 * np.sin(1.1 * t) + 0.3 * t
        pitch = 0.3 * np.sin(1.7 * t + 0.4)
        roll = 0.25 * np.sin(2.3 * t + 1.0)
        rates = (0.88 * np.cos(1.1 * t) + 0.3, 0.51 * np.cos(1.7 * t + 0.4), 0.575 * np.cos(2.3 * t + 1.0))
        return (yaw, pitch, roll), rates

    def R(self, t):
        (y, p, r), _ = self.angles(t)
        return rot_z(y) @ rot_y(p) @ rot_x(r)

    def p(self, t):
        return np.array([2.0 * np.sin(0.9 * t), 1.5 * np.cos(1.3 * t), 0.5 * np.sin(2.1 * t)])

    def v(self, t):
        return np.array([1.8 * np.cos(0.9 * t), -1.95 * np.sin(1.3 * t), 1.05 * np.cos(2.1 * t)])

    def a(self, t):
        return np.array([-1.62 * np.sin(0.9 * t), -2.535 * np.cos(1.3 * t), -2.205 * np.sin(2.1 * t)])

    def gyro(self, t):
        (_, p, r), (dy, dp, dr) = self.angles(t)
        Rx, Ry = rot_x(r), rot_y(p)
        return Rx.T @ Ry.T @ np.array([0, 0, dy]) + Rx.T @ np.array([0, dp, 0]) + np.array([dr, 0, 0])

    def accel(self, t):
        return self.R(t).T @ (self.a(t) + np.array([0.0, 0.0, G0]))

    def samples(self, rate_hz, duration_s, bg=0.0, ba=0.0):
        k = np.arange(int(round(duration_s * rate_hz)) + 1)
        t_ns = EPOCH_NS + (k * round(1e9 / rate_hz)).astype(np.int64)
        t = (t_ns - EPOCH_NS) * 1e-9
        gyro = np.array([self.gyro(x) for x in t]) + bg
        accel = np.array([self.accel(x) for x in t]) + ba
        return t_ns, gyro, accel

    def truth(self, t0, t1):
        """(dR, dv, dp) between times t0 and t1 (s)."""
        R0, dt = self.R(t0), t1 - t0
        g_W = np.array([0.0, 0.0, -G0])
        dv = R0.T @ (self.v(t1) - self.v(t0) - g_W * dt)
        dp = R0.T @ (self.p(t1) - self.p(t0) - self.v(t0) * dt - 0.5 * g_W * dt * dt)
        return R0.T @ self.R(t1), dv, dp


def test_gyro_model_matches_finite_differences_of_rotation():
    m = SineMotion()
    t, h = 0.77, 1e-6
    w_fd = so3_log(m.R(t).T @ m.R(t + h)) / h
    np.testing.assert_allclose(m.gyro(t + 0.5 * h), w_fd, atol=1e-8)


def test_constant_rate_and_body_specific_force_closed_form():
    w = np.array([0.4, -0.9, 1.3])
    a = np.array([0.5, 1.0, -2.0])
    n = 2001
    t_ns = np.arange(n, dtype=np.int64) * 1_000_000
    T = 2.0
    out = Preintegrator(np.zeros(3), np.zeros(3)).integrate(t_ns, np.tile(w, (n, 1)), np.tile(a, (n, 1)),
                                                           0, 2_000_000_000)
    k = np.linalg.norm(w)
    N = skew(w / k)
    # int_0^T Exp(w u) du and int_0^T (T - u) Exp(w u) du, by the Rodrigues formula
    int1 = T * np.eye(3) + (1 - np.cos(k * T)) / k * N + (T - np.sin(k * T) / k) * N @ N
    int2 = (T * T / 2 * np.eye(3) + (T / k - np.sin(k * T) / k**2) * N
            + (T * T / 2 - (1 - np.cos(k * T)) / k**2) * N @ N)
    np.testing.assert_allclose(out.dR, so3_exp(w * T), atol=1e-13)
    np.testing.assert_allclose(out.dv, int1 @ a, atol=1e-6)
    np.testing.assert_allclose(out.dp, int2 @ a, atol=1e-6)
    assert out.dt == pytest.approx(T) and out.n_intervals == 2000 and out.cov is None


def test_constant_acceleration_without_rotation_is_exact():
    n = 11
    t_ns = np.arange(n, dtype=np.int64) * 100_000_000
    a = np.array([1.0, -2.0, 3.0])
    out = Preintegrator(np.zeros(3), np.zeros(3)).integrate(t_ns, np.zeros((n, 3)), np.tile(a, (n, 1)),
                                                           50_000_000, 950_000_000)
    np.testing.assert_allclose(out.dR, np.eye(3), atol=0)
    np.testing.assert_allclose(out.dv, a * 0.9, atol=1e-14)
    np.testing.assert_allclose(out.dp, 0.5 * a * 0.81, atol=1e-14)


def test_sinusoidal_motion_at_1khz_matches_truth_between_off_sample_stamps():
    m = SineMotion()
    bg = np.array([0.01, -0.02, 0.015])
    ba = np.array([0.1, -0.05, 0.2])
    t_ns, gyro, accel = m.samples(1000.0, 2.0, bg, ba)
    t0_ns, t1_ns = EPOCH_NS + 300_400_000, EPOCH_NS + 1_700_250_123
    out = Preintegrator(bg, ba).integrate(t_ns, gyro, accel, t0_ns, t1_ns)
    dR, dv, dp = m.truth((t0_ns - EPOCH_NS) * 1e-9, (t1_ns - EPOCH_NS) * 1e-9)
    assert np.linalg.norm(so3_log(dR.T @ out.dR)) < 1e-6  # trapezoid error T dt^2 |w"| / 12
    np.testing.assert_allclose(out.dv, dv, atol=5e-6)
    np.testing.assert_allclose(out.dp, dp, atol=5e-6)
    # the end state follows from the start state and gravity
    t0, t1 = (t0_ns - EPOCH_NS) * 1e-9, (t1_ns - EPOCH_NS) * 1e-9
    R1, p1, v1 = out.predict(m.R(t0), m.p(t0), m.v(t0), G0)
    np.testing.assert_allclose(R1, m.R(t1), atol=1e-6)
    np.testing.assert_allclose(p1, m.p(t1), atol=5e-6)
    np.testing.assert_allclose(v1, m.v(t1), atol=5e-6)


def test_error_shrinks_quadratically_with_rate():
    m = SineMotion()
    errs = []
    for rate in (100.0, 200.0, 400.0):
        t_ns, gyro, accel = m.samples(rate, 1.5)
        out = Preintegrator(np.zeros(3), np.zeros(3)).integrate(t_ns, gyro, accel, t_ns[0], t_ns[-1])
        _, dv, dp = m.truth(0.0, 1.5)
        errs.append(np.linalg.norm(out.dp - dp) + np.linalg.norm(out.dv - dv))
    assert errs[0] / errs[1] > 3.0 and errs[1] / errs[2] > 3.0  # second order: about 4 per halving


def reintegrate(t_ns, gyro, accel, bg, ba):
    return Preintegrator(bg, ba).integrate(t_ns, gyro, accel, t_ns[3] + 1234, t_ns[-5] - 777)


def test_bias_jacobians_match_finite_differences():
    m = SineMotion()
    t_ns, gyro, accel = m.samples(200.0, 1.5)
    bg = np.array([0.02, -0.01, 0.03])
    ba = np.array([0.2, 0.1, -0.3])
    base = reintegrate(t_ns, gyro, accel, bg, ba)
    h = 1e-6
    J = {name: np.zeros((3, 3)) for name in ("R_bg", "v_bg", "v_ba", "p_bg", "p_ba")}
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        plus, minus = reintegrate(t_ns, gyro, accel, bg + e, ba), reintegrate(t_ns, gyro, accel, bg - e, ba)
        J["R_bg"][:, k] = (so3_log(base.dR.T @ plus.dR) - so3_log(base.dR.T @ minus.dR)) / (2 * h)
        J["v_bg"][:, k] = (plus.dv - minus.dv) / (2 * h)
        J["p_bg"][:, k] = (plus.dp - minus.dp) / (2 * h)
        plus, minus = reintegrate(t_ns, gyro, accel, bg, ba + e), reintegrate(t_ns, gyro, accel, bg, ba - e)
        J["v_ba"][:, k] = (plus.dv - minus.dv) / (2 * h)
        J["p_ba"][:, k] = (plus.dp - minus.dp) / (2 * h)
    for name, fd in J.items():
        np.testing.assert_allclose(getattr(base, "J_" + name), fd, atol=1e-7 * max(1.0, np.abs(fd).max()),
                                   err_msg=name)


def test_first_order_correction_predicts_reintegration():
    m = SineMotion()
    t_ns, gyro, accel = m.samples(200.0, 1.5)
    base = reintegrate(t_ns, gyro, accel, np.zeros(3), np.zeros(3))
    dbg, dba = np.array([2e-3, -1e-3, 1.5e-3]), np.array([0.03, -0.02, 0.05])
    new = reintegrate(t_ns, gyro, accel, dbg, dba)
    dR, dv, dp = base.corrected(dbg, dba)
    change = np.linalg.norm(new.dp - base.dp)
    assert change > 1e-2
    assert np.linalg.norm(dp - new.dp) < 1e-2 * change
    assert np.linalg.norm(dv - new.dv) < 1e-2 * np.linalg.norm(new.dv - base.dv)
    assert np.linalg.norm(so3_log(dR.T @ new.dR)) < 1e-2 * np.linalg.norm(so3_log(base.dR.T @ new.dR))


@pytest.mark.slow
def test_covariance_matches_monte_carlo():
    m = SineMotion()
    rate, sg, sa = 200.0, 0.01, 0.1
    t_ns, gyro, accel = m.samples(rate, 1.0)
    pre = Preintegrator(np.zeros(3), np.zeros(3), sg, sa)
    nominal = pre.integrate(t_ns, gyro, accel, t_ns[0], t_ns[-1])
    rng = np.random.default_rng(5)
    runs = 1500
    errs = np.empty((runs, 9))
    for r in range(runs):
        ng = gyro + rng.normal(scale=sg * np.sqrt(rate), size=gyro.shape)
        na = accel + rng.normal(scale=sa * np.sqrt(rate), size=accel.shape)
        out = pre.integrate(t_ns, ng, na, t_ns[0], t_ns[-1])
        errs[r] = np.r_[so3_log(nominal.dR.T @ out.dR), out.dv - nominal.dv, out.dp - nominal.dp]
    mc = np.cov(errs, rowvar=False)
    L = np.linalg.cholesky(nominal.cov)
    white = np.linalg.solve(L, np.linalg.solve(L, mc).T)  # L^-1 mc L^-T, ~ identity if cov is right
    np.testing.assert_allclose(np.diag(white), 1.0, atol=0.15)
    off = white - np.diag(np.diag(white))
    assert np.abs(off).max() < 0.15
    # cross terms rotation-velocity are large for this motion: they must be there in the prediction
    corr = nominal.cov[0:3, 3:6] / np.sqrt(np.outer(np.diag(nominal.cov)[:3], np.diag(nominal.cov)[3:6]))
    assert np.abs(corr).max() > 0.3


def test_zero_length_interval_and_bad_input():
    t_ns = np.arange(5, dtype=np.int64) * 10_000_000
    gyro, accel = np.ones((5, 3)), np.ones((5, 3))
    pre = Preintegrator(np.zeros(3), np.zeros(3), 1e-3, 1e-2)
    out = pre.integrate(t_ns, gyro, accel, 15_000_000, 15_000_000)
    np.testing.assert_array_equal(out.dR, np.eye(3))
    assert out.dt == 0.0 and np.all(out.cov == 0.0)
    with pytest.raises(DataError, match="do not cover"):
        pre.integrate(t_ns, gyro, accel, 0, 41_000_000)
    with pytest.raises(DataError, match="ends before"):
        pre.integrate(t_ns, gyro, accel, 20_000_000, 10_000_000)
    with pytest.raises(DataError, match="strictly increasing at sample 2"):
        pre.integrate(t_ns[[0, 1, 1, 3, 4]], gyro, accel, 0, 30_000_000)
    bad = gyro.copy()
    bad[3, 1] = np.nan
    with pytest.raises(DataError, match="gyro sample 3"):
        pre.integrate(t_ns, bad, accel, 25_000_000, 35_000_000)
    pre.integrate(t_ns, bad, accel, 0, 10_000_000)  # a bad sample outside the interval is not used
    with pytest.raises(DataError, match=r"shape \(5, 3\)"):
        pre.integrate(t_ns, gyro[:4], accel, 0, 10)
    with pytest.raises(DataError, match="integer"):
        pre.integrate(t_ns * 1e-9, gyro, accel, 0, 10)
    with pytest.raises(EstimatorError, match="both"):
        Preintegrator(np.zeros(3), np.zeros(3), gyro_noise_density=1e-3)
    with pytest.raises(EstimatorError, match="bg"):
        Preintegrator(np.zeros(2), np.zeros(3))


def test_integrate_many_matches_separate_integrations():
    m = SineMotion()
    t_ns, gyro, accel = m.samples(200.0, 2.0)
    pre = Preintegrator(np.array([0.01, 0.0, -0.02]), np.array([0.1, 0.2, 0.0]), 1e-3, 1e-2)
    t0 = int(t_ns[7]) + 1_234_567
    ends = np.array([t0 + 1_500_000_000, t0, int(t_ns[100]), t0 + 333_333_333, t0 + 333_333_333],
                    dtype=np.int64)
    many = pre.integrate_many(t_ns, gyro, accel, t0, ends)
    assert [p.t1_ns for p in many] == ends.tolist()
    for p, t1 in zip(many, ends, strict=True):
        one = pre.integrate(t_ns, gyro, accel, t0, int(t1))
        assert p.dt == one.dt
        # identical up to the O(dt^2) effect of the extra interpolated nodes at the other ends
        np.testing.assert_allclose(p.dR, one.dR, atol=1e-7)
        np.testing.assert_allclose(p.dv, one.dv, atol=1e-6)
        np.testing.assert_allclose(p.dp, one.dp, atol=1e-6)
        np.testing.assert_allclose(p.J_p_bg, one.J_p_bg, atol=1e-6)
        np.testing.assert_allclose(p.cov, one.cov, rtol=1e-3, atol=1e-12)
    with pytest.raises(DataError, match="ends before"):
        pre.integrate_many(t_ns, gyro, accel, t0, np.array([t0 - 1, t0 + 5], dtype=np.int64))
    with pytest.raises(DataError, match="integer"):
        pre.integrate_many(t_ns, gyro, accel, t0, np.array([0.5]))
