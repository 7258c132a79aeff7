"""Anchored inverse-depth landmarks: Jacobians vs finite differences, anchor change invariance."""

from __future__ import annotations

import numpy as np
import pytest

from runtime.msckf.landmark_repr import anchored_to_global, global_to_anchored
from runtime.msckf.so3_kernels import exp3
from runtime.msckf.state import Landmark, State
from runtime.msckf.state_helper import augment_clone
from runtime.msckf.update_slam import change_anchor

R_IC = exp3(np.array([1.2, -1.2, 1.2]) / np.sqrt(3))
p_IC = np.array([-0.02, -0.06, 0.01])


def _fd(f, x0: np.ndarray, plus, eps: float = 1e-6) -> np.ndarray:
    """Central differences of f over a 3-dof perturbation plus(x0, d)."""
    cols = []
    for j in range(3):
        d = np.zeros(3)
        d[j] = eps
        cols.append((f(plus(x0, d)) - f(plus(x0, -d))) / (2 * eps))
    return np.array(cols).T


def test_anchored_jacobians_match_finite_differences() -> None:
    R_A = exp3(np.array([0.3, -0.1, 0.7]))
    p_A = np.array([1.0, -2.0, 0.5])
    lam = np.array([0.1, -0.2, 0.25])
    add = lambda x, d: x if d is None else x + d  # noqa: E731
    rot = lambda R, d: R if d is None else R @ exp3(d)  # noqa: E731
    p_O, J_lam, J_anc, J_ext = anchored_to_global(lam, R_A, p_A, R_IC, p_IC)
    num = _fd(lambda v: anchored_to_global(v, R_A, p_A, R_IC, p_IC)[0], lam, add)
    assert np.allclose(num, J_lam, atol=1e-6)
    assert np.allclose(
        _fd(lambda R: anchored_to_global(lam, R, p_A, R_IC, p_IC)[0], R_A, rot), J_anc[:, :3], atol=1e-6
    )
    assert np.allclose(J_anc[:, 3:], np.eye(3))
    assert np.allclose(
        _fd(lambda R: anchored_to_global(lam, R_A, p_A, R, p_IC)[0], R_IC, rot), J_ext[:, :3], atol=1e-6
    )
    assert np.allclose(
        _fd(lambda p: anchored_to_global(lam, R_A, p_A, R_IC, p)[0], p_IC, add), J_ext[:, 3:], atol=1e-6
    )
    lam2, Jp, Ja, Je = global_to_anchored(p_O, R_A, p_A, R_IC, p_IC)
    assert np.allclose(lam2, lam)
    assert np.allclose(Jp @ J_lam, np.eye(3), atol=1e-9)  # inverse maps
    assert np.allclose(
        _fd(lambda R: global_to_anchored(p_O, R, p_A, R_IC, p_IC)[0], R_A, rot), Ja[:, :3], atol=1e-6
    )
    assert np.allclose(
        _fd(lambda p: global_to_anchored(p_O, R_A, p, R_IC, p_IC)[0], p_A, add), Ja[:, 3:], atol=1e-6
    )
    assert np.allclose(
        _fd(lambda R: global_to_anchored(p_O, R_A, p_A, R, p_IC)[0], R_IC, rot), Je[:, :3], atol=1e-6
    )
    assert np.allclose(
        _fd(lambda p: global_to_anchored(p_O, R_A, p_A, R_IC, p)[0], p_IC, add), Je[:, 3:], atol=1e-6
    )


def test_anchor_change_keeps_the_point_and_its_covariance() -> None:
    rng = np.random.default_rng(4)
    st = State(R_IC, p_IC, 0.0, False, True)
    n0 = st.size
    A = rng.standard_normal((n0, n0))
    st.P = A @ A.T * 1e-3 + np.eye(n0) * 1e-3
    st.R, st.p = exp3(np.array([0.1, 0.2, 0.3])), np.array([0.5, 0.0, 1.0])
    old = augment_clone(st, 1, np.zeros(3))
    st.R, st.p = exp3(np.array([0.2, 0.1, 0.6])), np.array([0.9, 0.3, 1.1])
    st.P[:15, :15] += np.eye(15) * 1e-3
    new = augment_clone(st, 2, np.zeros(3))
    lam = np.array([0.05, -0.1, 0.3])
    idx = st.add_variable(3, np.diag([1e-4, 1e-4, 1e-3]), 1e-5 * rng.standard_normal((3, st.size)))
    lm = Landmark(7, lam.copy(), lam.copy(), idx, anchor_t=1)
    st.slam[7] = lm
    B = rng.standard_normal((st.size, st.size))
    st.P = B @ B.T * 1e-3 + np.eye(st.size) * 1e-4  # a generic joint covariance
    assert np.all(np.linalg.eigvalsh(st.P) > 0)

    def point_jacobian(lmk: Landmark) -> tuple[np.ndarray, np.ndarray]:
        a = st.clones[lmk.anchor_t]
        p_O, J_lam, J_anc, J_ext = anchored_to_global(lmk.p, a.R, a.p, st.R_IC, st.p_IC)
        G = np.zeros((3, st.size))
        G[:, lmk.idx : lmk.idx + 3] = J_lam
        G[:, a.idx : a.idx + 6] += J_anc
        G[:, st.idx_ext : st.idx_ext + 6] += J_ext
        return p_O, G

    p0, G0 = point_jacobian(lm)
    cov0 = G0 @ st.P @ G0.T
    cross0 = G0 @ st.P[:, :15]
    change_anchor(st, lm, 2)
    assert lm.anchor_t == 2
    p1, G1 = point_jacobian(lm)
    assert np.allclose(p1, p0)
    assert np.allclose(G1 @ st.P @ G1.T, cov0)  # same point uncertainty
    assert np.allclose(G1 @ st.P[:, :15], cross0)  # same correlation with the IMU
    assert np.all(np.linalg.eigvalsh(st.P) > -1e-12)  # the linear map keeps it PSD
    assert new.idx > old.idx


def test_slam_rows_anchored_jacobians_match_finite_differences() -> None:
    from runtime.msckf.update_slam import slam_rows

    prm = np.array(
        [458.654, 457.296, 367.215, 248.375, -0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0]
    )
    R_c, p_c = exp3(np.array([0.05, 0.1, -0.05])), np.array([0.3, 0.1, 0.0])  # measuring clone
    R_a, p_a = np.eye(3), np.zeros(3)  # anchor clone
    lam = np.array([0.05, -0.04, 0.25])
    P = np.eye(40)

    def rows(Rc, pc, Ra, pa, lm, Ric, pic):
        uv = np.array([[300.0, 200.0]])
        return slam_rows(
            P,
            0,
            12,
            np.array([30]),
            np.array([6]),
            Rc[None],
            pc[None],
            Rc[None],
            pc[None],
            uv,
            lm[None],
            lm[None],
            Ra[None],
            pa[None],
            Ra[None],
            pa[None],
            Ric,
            pic,
            1,
            prm,
            1.0,
        )

    ok, _, r, Hc, Ha, He, Hl, _ = rows(R_c, p_c, R_a, p_a, lam, R_IC, p_IC)
    assert ok[0]
    eps = 1e-6

    def num(f) -> np.ndarray:
        out = []
        for j in range(3):
            d = np.zeros(3)
            d[j] = eps
            out.append(-(f(d)[2][0] - f(-d)[2][0]) / (2 * eps))
        return np.array(out).T

    assert np.allclose(
        num(lambda d: rows(R_c @ exp3(d), p_c, R_a, p_a, lam, R_IC, p_IC)), Hc[0][:, :3], atol=1e-3
    )
    assert np.allclose(num(lambda d: rows(R_c, p_c + d, R_a, p_a, lam, R_IC, p_IC)), Hc[0][:, 3:], atol=1e-3)
    assert np.allclose(
        num(lambda d: rows(R_c, p_c, R_a @ exp3(d), p_a, lam, R_IC, p_IC)), Ha[0][:, :3], atol=1e-3
    )
    assert np.allclose(num(lambda d: rows(R_c, p_c, R_a, p_a + d, lam, R_IC, p_IC)), Ha[0][:, 3:], atol=1e-3)
    assert np.allclose(
        num(lambda d: rows(R_c, p_c, R_a, p_a, lam, R_IC @ exp3(d), p_IC)), He[0][:, :3], atol=1e-3
    )
    assert np.allclose(num(lambda d: rows(R_c, p_c, R_a, p_a, lam, R_IC, p_IC + d)), He[0][:, 3:], atol=1e-3)
    assert np.allclose(num(lambda d: rows(R_c, p_c, R_a, p_a, lam + d, R_IC, p_IC)), Hl[0], atol=1e-3)


def test_slam_rows_mahalanobis_distance_against_numpy() -> None:
    """d2 = r^T (H P H^T + sigma^2 I)^-1 r over the touched columns (clone, extrinsics, anchor, landmark),
    with a generic correlated covariance: the kernel's block-free projection against numpy's."""
    from runtime.msckf.update_slam import slam_rows

    prm = np.array([458.654, 457.296, 367.215, 248.375, -0.28340811, 0.07395907, 0.00019359, 1.76187114e-05,
                    0.0])
    rng = np.random.default_rng(3)
    B = rng.standard_normal((40, 40))
    P = B @ B.T * 1e-4 + np.eye(40) * 1e-5
    R_c, p_c = exp3(np.array([0.05, 0.1, -0.05])), np.array([0.3, 0.1, 0.0])
    lam = np.array([[0.05, -0.04, 0.25], [-0.1, 0.08, 0.4]])
    uv = np.array([[300.0, 200.0], [420.0, 260.0]])
    eye = np.tile(np.eye(3), (2, 1, 1))
    out = slam_rows(P, 0, 12, np.array([30, 33]), np.array([6, 6]), R_c[None], p_c[None], R_c[None],
                    p_c[None], uv, lam, lam, eye, np.zeros((2, 3)), eye, np.zeros((2, 3)), R_IC, p_IC, 1,
                    prm, 1.5)
    ok, d2, r, Hc, Ha, He, Hl = out[:7]
    assert ok.all()
    for i, li in enumerate((30, 33)):
        cols = np.r_[0:6, 12:18, 6:12, li:li + 3]
        H = np.hstack([Hc[i], He[i], Ha[i], Hl[i]])
        S = H @ P[np.ix_(cols, cols)] @ H.T + 1.5 ** 2 * np.eye(2)
        assert d2[i] == pytest.approx(float(r[i] @ np.linalg.solve(S, r[i])), rel=1e-9)


@pytest.mark.parametrize(("with_extrinsics", "behind_fej_anchor"),
                         [(True, False), (False, False), (False, True)])
def test_anchor_change_kernel_against_finite_differences(with_extrinsics: bool,
                                                         behind_fej_anchor: bool) -> None:
    """The kernel's new lam, its FEJ, and the landmark's covariance rows J P[cols], J the finite-difference
    Jacobian of lam_new = g2a(a2g(lam, old anchor), new anchor) at the current point expressed through the
    anchors' first estimates (perturbed away from their current values); extrinsics estimated or not; the
    fallback to the stored FEJ when the point lies behind the first-estimate anchor."""
    from runtime.msckf.update_slam import anchor_change_kernel

    rng = np.random.default_rng(5)
    n, oidx, nidx, lidx, eidx = 45, 18, 24, 36, (12 if with_extrinsics else -1)
    B = rng.standard_normal((n, n))
    P = B @ B.T * 1e-3 + np.eye(n) * 1e-4
    R_o, p_o = exp3(np.array([0.1, -0.2, 0.3])), np.array([0.5, -0.2, 1.0])
    R_n, p_n = exp3(np.array([0.3, 0.1, -0.2])), np.array([0.9, 0.1, 1.2])
    Rf_o, pf_o = R_o @ exp3(np.array([0.01, -0.02, 0.015])), p_o + np.array([0.01, 0.02, -0.01])
    Rf_n, pf_n = R_n @ exp3(np.array([-0.02, 0.01, 0.01])), p_n + np.array([-0.01, 0.01, 0.02])
    if behind_fej_anchor:   # the first-estimate anchor looks the other way: the stored FEJ is used
        Rf_o = Rf_o @ R_IC @ exp3(np.array([np.pi, 0.0, 0.0])) @ R_IC.T
    lam, lam_fej = np.array([0.1, -0.08, 0.25]), np.array([0.11, -0.07, 0.24])

    def f(lm, Ro, po, Rn, pn, Ric, pic):
        return global_to_anchored(anchored_to_global(lm, Ro, po, Ric, pic)[0], Rn, pn, Ric, pic)[0]

    p_O = anchored_to_global(lam, R_o, p_o, R_IC, p_IC)[0]
    lam_o_fej = global_to_anchored(p_O, Rf_o, pf_o, R_IC, p_IC)[0]
    assert (lam_o_fej[2] < 0) == behind_fej_anchor
    if behind_fej_anchor:
        lam_o_fej = lam_fej
    x0 = (lam_o_fej, Rf_o, pf_o, Rf_n, pf_n, R_IC, p_IC)
    eps, cols, J = 1e-6, [], []
    for arg, col0, kind in ((0, lidx, "add"), (1, oidx, "rot"), (2, oidx + 3, "add"), (3, nidx, "rot"),
                            (4, nidx + 3, "add"), (5, eidx, "rot"), (6, eidx + 3, "add")):
        if col0 < 0 or (arg >= 5 and not with_extrinsics):
            continue
        for j in range(3):
            d = np.zeros(3)
            d[j] = eps
            plus, minus = list(x0), list(x0)
            plus[arg] = x0[arg] @ exp3(d) if kind == "rot" else x0[arg] + d
            minus[arg] = x0[arg] @ exp3(-d) if kind == "rot" else x0[arg] - d
            J.append((f(*plus) - f(*minus)) / (2 * eps))
            cols.append(col0 + j)
    J = np.array(J).T
    cols = np.array(cols)
    expected_row = J @ P[cols, :]
    expected_corner = J @ P[np.ix_(cols, cols)] @ J.T
    P_new = P.copy()
    lam_new, lam_new_fej = anchor_change_kernel(P_new, lam, lam_fej, R_o, p_o, Rf_o, pf_o, oidx, R_n, p_n,
                                                Rf_n, pf_n, nidx, R_IC, p_IC, lidx, eidx)
    np.testing.assert_allclose(lam_new, f(lam, R_o, p_o, R_n, p_n, R_IC, p_IC), atol=1e-12)
    np.testing.assert_allclose(lam_new_fej, f(*x0), atol=1e-12)
    li = np.arange(lidx, lidx + 3)
    others = np.setdiff1d(np.arange(n), li)
    np.testing.assert_allclose(P_new[np.ix_(li, others)], expected_row[:, others], rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(P_new[np.ix_(others, li)], expected_row[:, others].T, rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(P_new[np.ix_(li, li)], expected_corner, rtol=1e-5, atol=1e-9)
    np.testing.assert_array_equal(P_new[np.ix_(others, others)], P[np.ix_(others, others)])
