"""Pose splines and motion presets: closed-form derivatives against finite differences."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.sim.motion import PRESETS, R_LEVEL, preset_spline
from drivers.sim.spline import PoseSpline, fit_pose_spline
from runtime.errors import ConfigError
from runtime.geometry.so3 import so3_exp, so3_log


def _random_spline(seed: int = 0) -> PoseSpline:
    rng = np.random.default_rng(seed)
    return PoseSpline(10**9, 0.3, rng.normal(size=(12, 3)), so3_exp(rng.normal(size=(12, 3)) * 0.8))


def test_derivatives_match_finite_differences() -> None:
    s = _random_spline()
    t = np.arange(s.t0_ns + 10**6, s.t_end_ns - 10**6, 7_919_321)
    h = 1000  # 1 us
    a, ap, am = s.sample(t), s.sample(t + h), s.sample(t - h)
    np.testing.assert_allclose((ap.p - am.p) / 2e-6, a.v, atol=1e-6)
    np.testing.assert_allclose((ap.v - am.v) / 2e-6, a.a, atol=1e-5)
    omega_fd = so3_log(np.einsum("nji,njk->nik", am.R, ap.R)) / 2e-6
    np.testing.assert_allclose(omega_fd, a.omega, atol=1e-6)


def test_spline_is_continuous_across_knots() -> None:
    s = _random_spline(1)
    knots = s.t0_ns + np.round(np.arange(1, 8) * s.dt_s * 1e9).astype(np.int64)
    lo, hi = s.sample(knots - 1), s.sample(knots + 1)
    assert np.abs(lo.a - hi.a).max() < 1e-5
    assert np.abs(lo.omega - hi.omega).max() < 1e-5


def test_query_outside_span_is_an_error() -> None:
    s = _random_spline()
    with pytest.raises(ConfigError):
        s.sample(np.array([s.t_end_ns + 1]))


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_presets_are_smooth_and_plausible(name: str) -> None:
    s = preset_spline(name, 12.0, seed=4)
    t = np.arange(s.t0_ns, s.t0_ns + int(12e9), 5_000_000)
    a = s.sample(t)
    assert np.all(np.isfinite(a.p))
    assert np.linalg.norm(a.a, axis=1).max() < 15.0
    assert np.linalg.norm(a.omega, axis=1).max() < 4.0
    assert a.p[:, 2].min() > 0.1  # above the floor plane z = 0
    pr = PRESETS[name]
    if pr.static_s > 0:
        rest = t < s.t0_ns + int(pr.static_s * 1e9)
        assert np.abs(a.v[rest]).max() == 0.0 and np.abs(a.omega[rest]).max() < 1e-12
        np.testing.assert_allclose(a.R[0], R_LEVEL, atol=1e-12)  # level, heading +x
        assert np.linalg.norm(a.v, axis=1).max() > 0.1  # then it moves


def test_constant_velocity_preset_starts_at_constant_velocity() -> None:
    pr = PRESETS["constant-velocity"]
    s = preset_spline("constant-velocity", 8.0, seed=2)
    t = np.arange(s.t0_ns, s.t0_ns + int(pr.constant_velocity_s * 1e9), 10_000_000)
    a = s.sample(t)
    np.testing.assert_allclose(a.v, np.tile([pr.speed_mps, 0.0, 0.0], (t.size, 1)), atol=1e-9)
    assert np.abs(a.a).max() < 1e-9 and np.abs(a.omega).max() < 1e-9


def test_presets_are_reproducible_and_seeded() -> None:
    a = preset_spline("euroc", 10.0, seed=3).control_p
    b = preset_spline("euroc", 10.0, seed=3).control_p
    c = preset_spline("euroc", 10.0, seed=4).control_p
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 0.1


def test_unknown_preset_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match="unknown motion preset"):
        preset_spline("loop-the-loop", 5.0)


def test_fit_recovers_a_smooth_trajectory() -> None:
    t = 10**9 + np.arange(0, 4000) * 2_500_000  # 10 s at 400 Hz
    ts = (t - t[0]) * 1e-9
    p = np.stack([np.sin(0.7 * ts), np.cos(0.5 * ts), 0.2 * ts], axis=1)
    R = so3_exp(np.stack([0.1 * np.sin(ts), 0.2 * np.cos(0.3 * ts), 0.5 * ts], axis=1))
    s = fit_pose_spline(t, p, R, dt_s=0.1)
    q = t[(t >= s.t0_ns) & (t <= s.t_end_ns)][50:-50]
    k = np.searchsorted(t, q)
    a = s.sample(q)
    assert np.abs(a.p - p[k]).max() < 1e-4
    ang = np.linalg.norm(so3_log(np.einsum("nji,njk->nik", R[k], a.R)), axis=1)
    assert ang.max() < 1e-3
