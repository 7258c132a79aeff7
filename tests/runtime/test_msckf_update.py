"""MSCKF update on a tiny synthetic window: it corrects perturbed clones; FEJ linearisation point."""
from __future__ import annotations

import numpy as np

from runtime.msckf.camera_kernels import CameraParams, distort_points, undistort_points
from runtime.msckf.config import MsckfConfig
from runtime.msckf.feature_db import Track
from runtime.msckf.so3_kernels import exp3, log3
from runtime.msckf.state import State
from runtime.msckf.state_helper import augment_clone
from runtime.msckf.track_linearization import linearize_tracks
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
    shift = np.array([0.0, 0.0, 0.02])
    for c in st.clones.values():       # first estimates: the truth shifted by 2 cm up
        c.p_fej = c.p_fej + shift

    def point(cfg: MsckfConfig) -> tuple[np.ndarray, np.ndarray]:
        p_O, p_lin, _, _, _ = linearize_tracks(st, tracks[:1], cfg, CAM)[0]
        return p_O, p_lin

    p_O, p_lin = point(MsckfConfig(fej_triangulation=True))
    # the current clones are the truth: p_O is the true point; the one from the FEJ poses shifts with them
    assert np.allclose(p_lin - p_O, shift, atol=1e-6)
    for cfg in (MsckfConfig(), MsckfConfig(use_fej=False, fej_triangulation=True)):
        p_O, p_lin = point(cfg)
        assert np.array_equal(p_lin, p_O)


def test_batched_linearisation_matches_the_measurement_model_per_track() -> None:
    """The packed kernel's rows for each track equal feature_jacobians on that track's own arrays, placed in
    the window's clone columns; a track seen by one clone is not linearised."""
    from runtime.msckf.measurement import feature_jacobians

    rng = np.random.default_rng(4)
    st, truth, tracks = _window(rng, perturb=True)
    short = Track(99, [2], [tracks[0].uv[2]], [tracks[0].xn[2]])
    lins = linearize_tracks(st, tracks[:5] + [short], MsckfConfig(), CAM)
    assert lins[-1] is None
    for tr, lin in zip(tracks[:5], lins[:5], strict=True):
        p_O, p_lin, r, Hx, Hf = lin
        Rc = np.array([st.clones[t].R for t in tr.t_ns])
        pc = np.array([st.clones[t].p for t in tr.t_ns])
        ok, r1, Hc1, _, Hf1 = feature_jacobians(Rc, pc, Rc, pc, np.array(tr.uv), p_O, p_O, R_IC, p_IC, 1,
                                                 PRM)
        assert ok and np.allclose(r, r1) and np.allclose(Hf, Hf1)
        for i, t in enumerate(tr.t_ns):
            o = 6 * t                  # clone k = slot k; no calibration columns
            assert np.allclose(Hx[2 * i:2 * i + 2, o:o + 6], Hc1[2 * i:2 * i + 2])
            assert np.all(np.delete(Hx[2 * i:2 * i + 2], np.s_[o:o + 6], axis=1) == 0.0)
        # the triangulated point reprojects onto the measured pixels within the perturbation's effect
        assert np.isfinite(p_O).all()


def test_an_update_the_filter_cannot_apply_uses_nothing(monkeypatch) -> None:
    """An innovation covariance that is not positive definite (here a covariance that lost definiteness)
    leaves the state untouched: each track's gate refuses it, and the stacked EKF update refuses it too;
    when the stacked update fails the MSCKF update reports it with no track used (issue 16: it was ignored
    and every gated track still counted as used)."""
    import runtime.msckf.update_msckf as update_msckf_module
    from runtime.msckf.state_helper import ekf_update
    from runtime.msckf.track_linearization import window_columns

    rng = np.random.default_rng(3)
    st, truth, tracks = _window(rng, perturb=True)
    c = st.clones[2]
    st.P[c.idx:c.idx + 6, :] *= -1.0    # symmetric, indefinite
    st.P[:, c.idx:c.idx + 6] *= -1.0
    st.P[c.idx:c.idx + 6, c.idx:c.idx + 6] *= -1.0 * 50.0
    P0, clones0 = st.P.copy(), {k: (v.R.copy(), v.p.copy()) for k, v in st.clones.items()}

    def untouched() -> bool:
        return np.array_equal(st.P, P0) and all(
            np.array_equal(st.clones[k].R, R) and np.array_equal(st.clones[k].p, p)
            for k, (R, p) in clones0.items())

    stats = msckf_update(st, tracks, MsckfConfig(chi2_multiplier=1e12), CAM)
    assert stats.used == 0 and stats.rows == 0 and stats.chi2_rejected == len(tracks) and untouched()
    cols, _ = window_columns(st)
    H = np.zeros((6, cols.size))
    H[:, 12:18] = np.eye(6)              # observe clone 2 directly: S = -50 P_22 + 1e-4 I, not PD
    assert not ekf_update(st, cols, H, np.ones(6), 0.01) and untouched()
    # the stacked update's failure, as the MSCKF update reports it (healthy covariance, failing update)
    st2, _, tracks2 = _window(rng, perturb=True)
    monkeypatch.setattr(update_msckf_module, "ekf_update", lambda *args: False)
    stats = msckf_update(st2, tracks2, MsckfConfig(chi2_multiplier=1e12), CAM)
    assert stats.update_failed == 1 and stats.used == 0 and stats.rows == 0


def test_the_gate_holds_beyond_the_quantile_table() -> None:
    """Past the table of 95 % quantiles the kernel uses the Wilson-Hilferty approximation: an outlier is
    still refused (the gate is never switched off), a good track still passes."""
    from runtime.msckf.state_helper import _CHI2_95
    from runtime.msckf.track_linearization import (
        CHI2_REJECTED,
        OK,
        WindowArrays,
        msckf_rows_packed,
        pack_tracks,
        tri_params,
        window_columns,
    )

    rng = np.random.default_rng(5)
    st, truth, tracks = _window(rng, perturb=False)
    bad = Track(500, list(tracks[1].t_ns), [u.copy() for u in tracks[1].uv], list(tracks[1].xn))
    bad.uv[2] = bad.uv[2] + 40.0
    cfg = MsckfConfig()
    cols, _ = window_columns(st)
    win = WindowArrays(st)
    ptr, slots, uv, xn = pack_tracks(st, win, [tracks[0], bad], CAM)
    for table in (_CHI2_95, _CHI2_95[:2]):      # 4 observations: 5 rows, beyond a 2-entry table
        status, _, _ = msckf_rows_packed(
            win.R, win.p, win.R_fej, win.p_fej, ptr, slots, uv, xn, st.R_IC, st.p_IC, CAM.code, CAM.params,
            tri_params(cfg), cfg.tri_gn_iterations, False, False, False, st.P[np.ix_(cols, cols)],
            cfg.sigma_pix, cfg.chi2_multiplier, table)
        assert status.tolist() == [OK, CHI2_REJECTED]
