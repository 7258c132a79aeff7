"""State helper: EKF update vs the textbook Kalman equations, marginalisation, clone augmentation,
delayed landmark initialisation vs a joint linear-Gaussian solution."""
from __future__ import annotations

import numpy as np

from runtime.msckf.state import State
from runtime.msckf.state_helper import (
    add_landmarks,
    augment_clone,
    compress,
    ekf_update,
    initialize_landmark,
    marginalize,
    split_landmark_rows,
)


def _state(n_extra_clones: int = 2, seed: int = 0) -> State:
    rng = np.random.default_rng(seed)
    st = State(np.eye(3), np.zeros(3), 0.0, False, False)
    A = rng.standard_normal((15, 15))
    st.P = A @ A.T * 0.01 + np.eye(15) * 0.01
    for k in range(n_extra_clones):
        st.v = rng.standard_normal(3)
        augment_clone(st, 1000 + k, np.zeros(3))
        st.P[:15, :15] += np.eye(15) * 0.01   # decorrelate a little, as propagation would
    return st


def test_ekf_update_matches_kalman_equations() -> None:
    st = _state()
    rng = np.random.default_rng(1)
    n = st.size
    cols = np.array([0, 1, 2, 15, 16, 17, 24, 25])
    H = rng.standard_normal((5, cols.size))
    r = rng.standard_normal(5)
    Hf = np.zeros((5, n))
    Hf[:, cols] = H
    P0 = st.P.copy()
    S = Hf @ P0 @ Hf.T + 0.3**2 * np.eye(5)
    K = P0 @ Hf.T @ np.linalg.inv(S)
    p0 = st.p.copy()
    assert ekf_update(st, cols, H, r, 0.3)
    assert np.allclose(st.P, P0 - K @ S @ K.T)
    assert np.allclose(st.p - p0, (K @ r)[3:6])


def test_qr_compression_preserves_the_update() -> None:
    rng = np.random.default_rng(2)
    H = rng.standard_normal((30, 6))
    r = rng.standard_normal(30)
    Hc, rc = compress(H, r)
    assert Hc.shape == (6, 6)
    assert np.allclose(Hc.T @ Hc, H.T @ H)          # same information
    assert np.allclose(Hc.T @ rc, H.T @ r)          # same information vector


def test_marginalization_keeps_remaining_block() -> None:
    st = _state(n_extra_clones=3)
    P0 = st.P.copy()
    times = st.clone_times()
    c_mid = st.clones[times[1]]
    keep = np.r_[0:c_mid.idx, c_mid.idx + 6:st.size]
    later_idx = st.clones[times[2]].idx
    marginalize(st, [times[1]], [])
    assert np.array_equal(st.P, P0[np.ix_(keep, keep)])
    assert st.clones[times[2]].idx == later_idx - 6


def test_clone_is_a_copy_of_the_imu_pose() -> None:
    st = _state(n_extra_clones=0)
    c = augment_clone(st, 5, np.zeros(3))
    P = st.P
    assert np.allclose(P[c.idx:c.idx + 3, c.idx:c.idx + 3], P[0:3, 0:3])
    assert np.allclose(P[c.idx + 3:c.idx + 6, 0:15], P[3:6, 0:15])


def test_time_offset_enters_the_clone() -> None:
    st = State(np.eye(3), np.zeros(3), 0.0, True, False)
    st.P = np.eye(16) * 1e-4
    st.v = np.array([1.0, 2.0, 3.0])
    w = np.array([0.1, 0.2, 0.3])
    c = augment_clone(st, 7, w)
    assert np.allclose(st.P[c.idx:c.idx + 3, st.idx_dt], w * 1e-4)
    assert np.allclose(st.P[c.idx + 3:c.idx + 6, st.idx_dt], st.v * 1e-4)


def test_landmark_initialisation_matches_joint_linear_solution() -> None:
    # a linear-Gaussian problem: z = Hx x + Hf f + n with f unknown (flat prior): the delayed
    # initialisation must give the same joint posterior as information-form elimination
    rng = np.random.default_rng(5)
    st = _state(n_extra_clones=1)
    n = st.size
    cols = np.arange(15, 21)
    M = 8
    Hx = rng.standard_normal((M, cols.size))
    Hf = rng.standard_normal((M, 3))
    r = rng.standard_normal(M) * 0.1
    sigma = 0.5
    P0 = st.P.copy()
    f0 = np.array([1.0, 2.0, 3.0])
    x0_p = st.p.copy()
    ok = initialize_landmark(st, 42, f0, cols, Hx, Hf, r, sigma, chi2_multiplier=1e6)
    assert ok
    # joint information form: prior on x, flat on f
    Hfull = np.zeros((M, n + 3))
    Hfull[:, cols] = Hx
    Hfull[:, n:] = Hf
    Lam = np.zeros((n + 3, n + 3))
    Lam[:n, :n] = np.linalg.inv(P0)
    Lam += Hfull.T @ Hfull / sigma**2
    Pj = np.linalg.inv(Lam)
    mean = Pj @ (Hfull.T @ r / sigma**2)
    assert np.allclose(st.P, Pj, atol=1e-8)
    assert np.allclose(st.slam[42].p, f0 + mean[n:], atol=1e-8)
    assert np.allclose(st.p - x0_p, mean[3:6], atol=1e-8)


def test_batched_landmark_initialisation_matches_the_joint_linear_solution() -> None:
    # three landmarks observed over the same window columns, added in one covariance copy, their remaining
    # rows applied in one stacked update afterwards (as delayed_init does): the joint posterior of state and
    # all landmarks must equal information-form elimination with a flat prior on every landmark
    rng = np.random.default_rng(11)
    st = _state(n_extra_clones=1)
    n = st.size
    cols = np.arange(15, 21)
    sigma, M, L = 0.4, 8, 3
    P0, x0_p = st.P.copy(), st.p.copy()
    Pcc = st.P[np.ix_(cols, cols)]
    rows, accepted, deferred = [], [], []
    for i in range(L):
        Hx, Hf = rng.standard_normal((M, cols.size)), rng.standard_normal((M, 3))
        r = rng.standard_normal(M) * 0.1
        rows.append((Hx, Hf, r))
        split = split_landmark_rows(Pcc, Hx, Hf, r, sigma, chi2_multiplier=1e6)
        assert split is not None
        F, Hx1, r1, Hx2, r2 = split
        accepted.append((10 + i, np.full(3, float(i)), None, F, Hx1, r1))
        deferred.append((Hx2, r2))
    lms = add_landmarks(st, cols, accepted, sigma)
    assert [lm.idx for lm in lms] == [n, n + 3, n + 6]
    H2, r2 = compress(np.vstack([h for h, _ in deferred]), np.concatenate([x for _, x in deferred]))
    assert ekf_update(st, cols, H2, r2, sigma)
    Hfull = np.zeros((M * L, n + 3 * L))
    for i, (Hx, Hf, _) in enumerate(rows):
        Hfull[M * i:M * (i + 1), cols] = Hx
        Hfull[M * i:M * (i + 1), n + 3 * i:n + 3 * i + 3] = Hf
    rall = np.concatenate([r for _, _, r in rows])
    Lam = np.zeros((n + 3 * L, n + 3 * L))
    Lam[:n, :n] = np.linalg.inv(P0)
    Lam += Hfull.T @ Hfull / sigma**2
    Pj = np.linalg.inv(Lam)
    mean = Pj @ (Hfull.T @ rall / sigma**2)
    assert np.allclose(st.P, Pj, atol=1e-8)
    for i in range(L):
        assert np.allclose(st.slam[10 + i].p, float(i) + mean[n + 3 * i:n + 3 * i + 3], atol=1e-8)
    assert np.allclose(st.p - x0_p, mean[3:6], atol=1e-8)


def test_landmark_initialisation_gate_uses_the_full_residual_size() -> None:
    # OpenVINS gates the projected rows (M - 3 of them) with the 95% chi-square quantile of all M rows;
    # scale one residual so that its Mahalanobis distance lies between the two quantiles
    from scipy.linalg import null_space
    from scipy.stats import chi2

    rng = np.random.default_rng(7)
    M = 8
    cols = np.arange(15, 21)
    Hx = rng.standard_normal((M, cols.size))
    Hf = rng.standard_normal((M, 3))
    sigma = 0.5
    base = _state(n_extra_clones=1)
    N = null_space(Hf.T)                      # independent projection onto the left nullspace
    S = N.T @ Hx @ base.P[np.ix_(cols, cols)] @ Hx.T @ N + sigma**2 * np.eye(M - 3)
    r0 = rng.standard_normal(M)
    d0 = float(r0 @ N @ np.linalg.solve(S, N.T @ r0))
    lo, hi = chi2.ppf(0.95, M - 3), chi2.ppf(0.95, M)
    for target, accepted in ((0.5 * (lo + hi), True), (hi * 1.05, False)):
        st = _state(n_extra_clones=1)
        r = r0 * np.sqrt(target / d0)
        ok = initialize_landmark(st, 1, np.zeros(3), cols, Hx, Hf, r, sigma, chi2_multiplier=1.0)
        assert ok is accepted, (target, lo, hi)
        assert (1 in st.slam) is accepted


def test_submatrix_by_runs_equals_the_gathered_submatrix() -> None:
    # the block-run copy that removes variables from P against numpy's gather, over random masks
    from runtime.msckf.state import _submatrix

    rng = np.random.default_rng(4)
    for _ in range(200):
        n = int(rng.integers(1, 40))
        P = rng.random((n, n))
        keep = rng.random(n) < 0.7
        k = np.flatnonzero(keep)
        assert np.array_equal(_submatrix(P, keep), P[np.ix_(k, k)])



def test_chi2_quantiles_are_scipy_stats_bit_for_bit_without_importing_it() -> None:
    """The filters' gate quantiles equal scipy.stats.chi2.ppf(0.95, dof) exactly, in the table and past it;
    the runtime does not import scipy.stats (about 1 s at every command's start on a 2-core machine)."""
    import subprocess
    import sys

    from scipy.stats import chi2

    from runtime.msckf.state_helper import chi2_95

    for dof in (1, 2, 3, 7, 40, 333, 2000, 2001, 4321):
        assert chi2_95(dof) == chi2.ppf(0.95, dof), dof
    code = ("import sys, runtime.session, runtime.pipeline, tools.commands.live, tools.commands.run; "
            "print('scipy.stats' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
