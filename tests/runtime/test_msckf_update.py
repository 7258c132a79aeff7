"""MSCKF update on a tiny synthetic window: it corrects perturbed clones; FEJ linearisation point."""
from __future__ import annotations

import numpy as np

from runtime.msckf.camera_kernels import CameraParams, distort_points, undistort_points
from runtime.msckf.config import MsckfConfig
from runtime.msckf.feature_db import Track
from runtime.msckf.so3_kernels import exp3, log3
from runtime.msckf.state import State
from runtime.msckf.state_helper import augment_clone
from runtime.msckf.track_linearization import linearization_point
from runtime.msckf.update_msckf import msckf_update

PRM = np.array([458.654, 457.296, 367.215, 248.375, -0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0])
CAM = CameraParams("radtan", PRM, 752, 480)
R_IC = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])    # camera looks along body x
p_IC = np.zeros(3)


def _window(rng: np.random.Generator, perturb: bool):
    st = State(R_IC, p_IC, 0.0, False, False)
    st.P = np.eye(15) * 1e-6
    truth = [(exp3(np.array([0.0, 0.0, 0.05 * k])), np.array([0.0, 0.3 * k, 0.0])) for k in range(4)]
    errs = [(np.zeros(3), np.zeros(3))] + [(0.01 * rng.standard_normal(3), 0.05 * rng.standard_normal(3))
                                           for _ in range(3)]
    for k, ((R, p), (dth, dp)) in enumerate(zip(truth, errs, strict=True)):
        st.R, st.p = (R @ exp3(dth), p + dp) if perturb else (R, p)
        c = augment_clone(st, k, np.zeros(3))
        if k > 0:   # independent prior of the later clones
            st.P[c.idx:c.idx + 3, c.idx:c.idx + 3] += np.eye(3) * 0.02**2
            st.P[c.idx + 3:c.idx + 6, c.idx + 3:c.idx + 6] += np.eye(3) * 0.1**2
    L = np.c_[rng.uniform(4, 8, 60), rng.uniform(-2, 3, 60), rng.uniform(-1.5, 1.5, 60)]
    tracks = []
    for j, p_O in enumerate(L):
        tr = Track(j)
        for k, (R, p) in enumerate(truth):
            pC = R_IC.T @ (R.T @ (p_O - p) - p_IC)
            uv = distort_points(1, PRM, (pC[:2] / pC[2])[None])
            tr.t_ns.append(k)
            tr.uv.append(uv[0])
            tr.xn.append(undistort_points(1, PRM, uv)[0])
        tracks.append(tr)
    return st, truth, tracks


def _errors(st: State, truth) -> np.ndarray:
    return np.array([np.r_[log3(st.clones[k].R.T @ R), p - st.clones[k].p] for k, (R, p) in enumerate(truth)])


def test_msckf_update_corrects_perturbed_clones() -> None:
    rng = np.random.default_rng(0)
    st, truth, tracks = _window(rng, perturb=True)
    observable = [0, 1, 2, 3, 5]   # all but y, the direction of motion: monocular scale comes from the prior
    before = np.abs(_errors(st, truth)[:, observable]).max()
    stats = msckf_update(st, tracks, MsckfConfig(chi2_multiplier=1e6), CAM)
    err = _errors(st, truth)
    assert stats.used == len(tracks) and stats.rows <= 24
    assert np.abs(err[:, observable]).max() < 0.2 * before, (before, err)
    for k in range(1, 4):          # what is left is consistent with the posterior covariance
        c = st.clones[k]
        P = st.P[c.idx:c.idx + 6, c.idx:c.idx + 6]
        assert err[k] @ np.linalg.solve(P, err[k]) < 22.5   # chi2(6) 99.9%


def test_msckf_update_leaves_a_perfect_window_alone() -> None:
    rng = np.random.default_rng(1)
    st, truth, tracks = _window(rng, perturb=False)
    msckf_update(st, tracks, MsckfConfig(), CAM)
    assert np.abs(_errors(st, truth)).max() < 1e-6


def test_linearization_point_uses_first_estimates() -> None:
    """With fej_triangulation (off by default, as OpenVINS) the point comes from the first estimates."""
    rng = np.random.default_rng(2)
    st, truth, tracks = _window(rng, perturb=False)
    tr = tracks[0]
    Rf = np.array([st.clones[k].R_fej for k in range(4)])
    pf = np.array([st.clones[k].p_fej for k in range(4)]) + np.array([0.0, 0.0, 0.02])   # shifted FEJ
    xn = np.array(tr.xn)
    p_cur = np.array([5.0, 1.0, 0.0])
    on = MsckfConfig(fej_triangulation=True)
    p_lin = linearization_point(st, on, Rf, pf, xn, p_cur)
    # the FEJ poses are the truth shifted by 2 cm up: the point triangulated from them shifts with them
    p_true = linearization_point(st, on, Rf, pf - np.array([0.0, 0.0, 0.02]), xn, p_cur)
    assert np.allclose(p_lin - p_true, [0.0, 0.0, 0.02], atol=1e-6)
    off = MsckfConfig()
    assert np.allclose(linearization_point(st, off, Rf, pf, xn, p_cur), p_cur)
    no_fej = MsckfConfig(use_fej=False, fej_triangulation=True)
    assert np.allclose(linearization_point(st, no_fej, Rf, pf, xn, p_cur), p_cur)


def test_an_update_the_filter_cannot_apply_uses_nothing() -> None:
    """An innovation covariance that is not positive definite (here a covariance that lost definiteness)
    leaves the state untouched and is reported as a failed update with no track used (issue 16: it was
    ignored and every gated track still counted as used)."""
    rng = np.random.default_rng(3)
    st, truth, tracks = _window(rng, perturb=True)
    c = st.clones[2]
    st.P[c.idx:c.idx + 6, :] *= -1.0    # symmetric, indefinite
    st.P[:, c.idx:c.idx + 6] *= -1.0
    st.P[c.idx:c.idx + 6, c.idx:c.idx + 6] *= -1.0 * 50.0
    P0, clones0 = st.P.copy(), {k: (v.R.copy(), v.p.copy()) for k, v in st.clones.items()}
    stats = msckf_update(st, tracks, MsckfConfig(chi2_multiplier=1e12), CAM)
    assert stats.update_failed == 1 and stats.used == 0 and stats.rows == 0
    assert np.array_equal(st.P, P0)
    assert all(np.array_equal(st.clones[k].R, R) and np.array_equal(st.clones[k].p, p)
               for k, (R, p) in clones0.items())
