"""Measurement model: Jacobians vs finite differences, nullspace projection, triangulation, distortion."""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from runtime.msckf.camera_kernels import distort_point, distort_points, undistort_points
from runtime.msckf.measurement import feature_jacobians, givens_left_nullspace
from runtime.msckf.so3_kernels import exp3
from runtime.msckf.triangulation import triangulate

PRM = np.array([458.654, 457.296, 367.215, 248.375, -0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0])
R_IC = exp3(np.array([1.2, -1.2, 1.2]) / np.sqrt(3) * 1.0)
p_IC = np.array([-0.02, -0.06, 0.01])


def _scene(m: int = 5, seed: int = 1):
    rng = np.random.default_rng(seed)
    Rc = np.array([exp3(0.1 * rng.standard_normal(3)) for _ in range(m)])
    pc = np.cumsum(0.2 * rng.standard_normal((m, 3)), axis=0)
    # a point about 4 m in front of the first camera
    p_C = np.array([0.3, -0.2, 4.0])
    p_O = Rc[0] @ (R_IC @ p_C + p_IC) + pc[0]
    uv = np.zeros((m, 2))
    for i in range(m):
        q = R_IC.T @ (Rc[i].T @ (p_O - pc[i]) - p_IC)
        u, v, _ = distort_point(1, PRM, q[0] / q[2], q[1] / q[2])
        uv[i] = u, v
    return Rc, pc, p_O, uv


def _residual(Rc, pc, p_O, R_ic, p_ic, uv):
    ok, r, *_ = feature_jacobians(Rc, pc, Rc, pc, uv, p_O, p_O, R_ic, p_ic, 1, PRM)
    assert ok
    return r


def test_jacobians_match_finite_differences() -> None:
    Rc, pc, p_O, uv = _scene()
    uv = uv + 0.5
    ok, r, Hc, He, Hf = feature_jacobians(Rc, pc, Rc, pc, uv, p_O, p_O, R_IC, p_IC, 1, PRM)
    assert ok
    eps = 1e-6
    # residual r = z - h: d r / d x = -d h / d x, and H is d h / d x (r ~ H dx after sign: z - h(x + dx))
    for i in range(Rc.shape[0]):
        for j in range(6):
            d = np.zeros(6)
            d[j] = eps
            Rp, pp = Rc.copy(), pc.copy()
            Rm, pm = Rc.copy(), pc.copy()
            Rp[i] = Rc[i] @ exp3(d[:3])
            pp[i] = pc[i] + d[3:]
            Rm[i] = Rc[i] @ exp3(-d[:3])
            pm[i] = pc[i] - d[3:]
            num = -(_residual(Rp, pp, p_O, R_IC, p_IC, uv) - _residual(Rm, pm, p_O, R_IC, p_IC, uv)) / (
                2 * eps
            )
            assert np.allclose(num[2 * i : 2 * i + 2], Hc[2 * i : 2 * i + 2, j], rtol=1e-5, atol=1e-4)
    for j in range(3):
        d = np.zeros(3)
        d[j] = eps
        num = -(_residual(Rc, pc, p_O + d, R_IC, p_IC, uv) - _residual(Rc, pc, p_O - d, R_IC, p_IC, uv)) / (
            2 * eps
        )
        assert np.allclose(num, Hf[:, j], rtol=1e-5, atol=1e-4)
        num = -(
            _residual(Rc, pc, p_O, R_IC @ exp3(d), p_IC, uv)
            - _residual(Rc, pc, p_O, R_IC @ exp3(-d), p_IC, uv)
        ) / (2 * eps)
        assert np.allclose(num, He[:, j], rtol=1e-5, atol=1e-4)
        num = -(_residual(Rc, pc, p_O, R_IC, p_IC + d, uv) - _residual(Rc, pc, p_O, R_IC, p_IC - d, uv)) / (
            2 * eps
        )
        assert np.allclose(num, He[:, 3 + j], rtol=1e-5, atol=1e-4)


def test_nullspace_projection_removes_feature_and_keeps_information() -> None:
    rng = np.random.default_rng(3)
    M, n = 10, 12
    Hf = rng.standard_normal((M, 3))
    Hx = rng.standard_normal((M, n))
    r = rng.standard_normal(M)
    Hx2, r2, Hf1, Hx1, r1 = givens_left_nullspace(Hf.copy(), Hx.copy(), r.copy())
    assert Hx2.shape == (M - 3, n)
    N = sla.null_space(Hf.T)  # closed-form left nullspace (orthonormal)
    # same information (Gram matrices) and same residual norm as the SVD nullspace projection
    assert np.allclose(Hx2.T @ Hx2, Hx.T @ N @ N.T @ Hx)
    assert np.isclose(r2 @ r2, r @ N @ N.T @ r)
    # a feature perturbation leaves the projected residual unchanged
    df = rng.standard_normal(3)
    _, r2b, *_ = givens_left_nullspace(Hf.copy(), Hx.copy(), r + Hf @ df)
    assert np.allclose(r2b, r2)
    # the top block is upper triangular and reproduces Hf (orthogonal transform)
    assert np.allclose(np.tril(Hf1, -1), 0.0)
    assert np.allclose(Hf1.T @ Hf1, Hf.T @ Hf)


def test_triangulation_exact_on_noiseless_data() -> None:
    Rc, pc, p_O, uv = _scene(m=6)
    xn = undistort_points(1, PRM, uv)
    ok, p = triangulate(Rc @ R_IC, pc + Rc @ p_IC, xn, 1e4, 0.1, 60.0, 40.0, 20)
    assert ok
    assert np.allclose(p, p_O, atol=1e-6)


def test_triangulation_rejects_tiny_baseline() -> None:
    Rc, pc, p_O, uv = _scene(m=3)
    pc = pc * 0 + pc[0]  # all cameras at one point: depth unobservable
    xn = undistort_points(1, PRM, uv)
    ok, _ = triangulate(Rc @ R_IC, pc + Rc @ p_IC, xn, 1e4, 0.1, 60.0, 40.0, 20)
    assert not ok


def test_radtan_matches_opencv_and_round_trips() -> None:
    import cv2

    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.6, 0.6, (50, 2))
    uv = distort_points(1, PRM, xy)
    K = np.array([[PRM[0], 0, PRM[2]], [0, PRM[1], PRM[3]], [0, 0, 1.0]])
    ref, _ = cv2.projectPoints(np.c_[xy, np.ones(50)], np.zeros(3), np.zeros(3), K, PRM[4:8])
    assert np.allclose(uv, ref.reshape(-1, 2), atol=1e-9)
    assert np.allclose(undistort_points(1, PRM, uv), xy, atol=1e-10)


def test_triangulation_baseline_is_perpendicular_to_the_ray() -> None:
    """The baseline of the depth/baseline check is the cameras' offset across the ray to the point (OpenVINS
    single_gaussnewton): 2 m of motion along the ray with 0.135 m across it at 6 m depth is a ratio of 44 and
    is rejected (the offset's full length would give 3); 0.18 m across (ratio 33) is accepted."""
    p = np.array([0.0, 0.0, 6.0])
    R = np.repeat(np.eye(3)[None], 4, 0)
    for across, ok_expected in ((0.135, False), (0.18, True)):
        pc = np.array([[0, 0, 0], [0, 0, -0.01], [across, 0, -2.0], [across, 0, -2.01]])
        v = p - pc
        xn = v[:, :2] / v[:, 2:3]
        # loose conditioning: the baseline decides
        ok, p_O = triangulate(R, pc, xn, 1e6, 0.1, 60.0, 40.0, 20)
        assert ok == ok_expected
        if ok:
            assert np.allclose(p_O, p, atol=1e-6)


def test_turning_in_place_triangulates_only_near_points_and_only_past_openvins_gates() -> None:
    """Turning in place at 0.6 rad/s, the camera moves only on its lever arm (6.3 cm): seen from 11 views
    over 0.5 s, a point 1.2 m away has a depth/baseline ratio of about 64 and cond(A) of about 4e4.
    OpenVINS's gates (cond 1e4, ratio 40) refuse it, so a filter that turns in place gets no visual update;
    our defaults (1e5, 70) take it and recover it exactly; a point 1.5 m away (ratio 80) is refused by both
    (BENCHMARKS "Triangulation gates for turning in place")."""
    from runtime.msckf.config import MsckfConfig

    cfg = MsckfConfig()
    defaults = (cfg.tri_max_cond, cfg.tri_min_dist, cfg.tri_max_dist, cfg.tri_max_baseline_ratio)
    openvins = (1e4, 0.1, 60.0, 40.0)
    assert defaults == (1e5, 0.1, 60.0, 70.0)
    R_OI = np.array([exp3(np.array([0.0, 0.0, 0.6 * 0.05 * k])) for k in range(11)])
    R_OC, p_OC = R_OI @ R_IC, R_OI @ p_IC
    for depth, ok_default in ((1.2, True), (1.5, False)):
        p_O = R_OC[0] @ np.array([0.2, -0.1, depth]) + p_OC[0]
        q = np.einsum("kji,kj->ki", R_OC, p_O - p_OC)
        xn = q[:, :2] / q[:, 2:3]
        ok, p = triangulate(R_OC, p_OC, xn, *defaults, 20)
        assert ok == ok_default
        if ok:
            assert np.allclose(p, p_O, atol=1e-6)
        assert not triangulate(R_OC, p_OC, xn, *openvins, 20)[0]
