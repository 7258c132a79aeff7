"""Navigation-state propagation (RK4) against an analytic helix and against preintegration."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from runtime.errors import DataError, EstimatorError
from runtime.geometry import so3_log
from runtime.imu import Preintegrator, integrate_state

G0 = 9.81
OMEGA, RADIUS, CLIMB, BETA, NU = 0.7, 3.0, 0.2, 0.4, 2.5


def rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def helix(t):
    """R_WI = Rz(OMEGA t) Ry(BETA sin(NU t)) on a climbing circle; returns R, p, v, gyro, accel."""
    R = rz(OMEGA * t) @ ry(BETA * np.sin(NU * t))
    c, s = np.cos(OMEGA * t), np.sin(OMEGA * t)
    p = np.array([RADIUS * c, RADIUS * s, CLIMB * t])
    v = np.array([-RADIUS * OMEGA * s, RADIUS * OMEGA * c, CLIMB])
    a = np.array([-RADIUS * OMEGA**2 * c, -RADIUS * OMEGA**2 * s, 0.0])
    gyro = ry(BETA * np.sin(NU * t)).T @ np.array([0.0, 0.0, OMEGA]) + np.array(
        [0.0, BETA * NU * np.cos(NU * t), 0.0])
    accel = R.T @ (a + np.array([0.0, 0.0, G0]))
    return R, p, v, gyro, accel


def sampled(rate_hz, duration_s, bg=0.0, ba=0.0):
    n = int(round(rate_hz * duration_s)) + 1
    t_ns = 5_000_000_000 + np.arange(n, dtype=np.int64) * int(round(1e9 / rate_hz))
    t = (t_ns - t_ns[0]) * 1e-9
    rows = [helix(x) for x in t]
    gyro = np.array([r[3] for r in rows]) + bg
    accel = np.array([r[4] for r in rows]) + ba
    return t_ns, t, gyro, accel


def test_rk4_follows_the_analytic_helix():
    t_ns, t, gyro, accel = sampled(500.0, 3.0)
    R0, p0, v0, _, _ = helix(0.0)
    traj = integrate_state(R0, p0, v0, (t_ns, gyro, accel), g=G0)
    assert np.array_equal(traj.t_ns, t_ns) and len(traj) == t.size
    R1, p1, v1, _, _ = helix(t[-1])
    assert np.linalg.norm(so3_log(R1.T @ traj.R[-1])) < 1e-6
    np.testing.assert_allclose(traj.v[-1], v1, atol=1e-5)
    np.testing.assert_allclose(traj.p[-1], p1, atol=1e-5)
    mid = t.size // 2
    np.testing.assert_allclose(traj.p[mid], helix(t[mid])[1], atol=1e-5)


def test_biases_are_subtracted_and_imu_sample_objects_accepted():
    @dataclass
    class Sample:
        t_ns: int
        gyro: np.ndarray
        accel: np.ndarray

    bg, ba = np.array([0.01, 0.02, -0.03]), np.array([0.2, -0.1, 0.05])
    t_ns, t, gyro, accel = sampled(400.0, 1.0, bg, ba)
    R0, p0, v0, _, _ = helix(0.0)
    objs = [Sample(int(a), g, f) for a, g, f in zip(t_ns, gyro, accel, strict=True)]
    traj = integrate_state(R0, p0, v0, objs, g=G0, bg=bg, ba=ba)
    R1, p1, v1, _, _ = helix(t[-1])
    np.testing.assert_allclose(traj.p[-1], p1, atol=1e-5)
    np.testing.assert_allclose(traj.v[-1], v1, atol=1e-5)


def test_propagation_and_preintegration_agree():
    t_ns, t, gyro, accel = sampled(1000.0, 2.0)
    R0, p0, v0, _, _ = helix(0.0)
    traj = integrate_state(R0, p0, v0, (t_ns, gyro, accel), g=G0)
    pre = Preintegrator(np.zeros(3), np.zeros(3)).integrate(t_ns, gyro, accel, t_ns[0], t_ns[-1])
    R1, p1, v1 = pre.predict(R0, p0, v0, G0)
    assert np.linalg.norm(so3_log(R1.T @ traj.R[-1])) < 1e-6
    np.testing.assert_allclose(p1, traj.p[-1], atol=1e-5)
    np.testing.assert_allclose(v1, traj.v[-1], atol=1e-5)


def test_at_rest_stays_at_rest():
    n = 101
    t_ns = np.arange(n, dtype=np.int64) * 5_000_000
    R0 = rz(0.3) @ ry(0.2)
    accel = np.tile(R0.T @ np.array([0.0, 0.0, G0]), (n, 1))
    traj = integrate_state(R0, np.ones(3), np.zeros(3), (t_ns, np.zeros((n, 3)), accel), g=G0)
    np.testing.assert_allclose(traj.p, np.ones((n, 3)), atol=1e-12)
    np.testing.assert_allclose(traj.R, np.broadcast_to(R0, (n, 3, 3)), atol=1e-14)


def test_bad_input():
    t_ns = np.arange(3, dtype=np.int64)
    with pytest.raises(EstimatorError, match="R_WI"):
        integrate_state(np.eye(4), np.zeros(3), np.zeros(3), (t_ns, np.zeros((3, 3)), np.zeros((3, 3))))
    with pytest.raises(EstimatorError, match="p must"):
        integrate_state(np.eye(3), np.zeros(2), np.zeros(3), (t_ns, np.zeros((3, 3)), np.zeros((3, 3))))
    with pytest.raises(DataError, match="accel"):
        integrate_state(np.eye(3), np.zeros(3), np.zeros(3), (t_ns, np.zeros((3, 3)), np.zeros((2, 3))))
    with pytest.raises(EstimatorError, match="at least one"):
        integrate_state(np.eye(3), np.zeros(3), np.zeros(3), [])
