"""The per-frame scale solve recovers injected per-frame depth scales (up to their geometric mean)."""
from __future__ import annotations

import numpy as np
from mapping_synth import window_poses

from runtime.mapping.frame_scales import PairMatches, solve_frame_scales


def _window_matches(scales_err, n_pts=200, outlier_frac=0.0, seed=0):
    """Points on a wall seen by 5 cameras; image i's depths are multiplied by scales_err[i]."""
    rng = np.random.default_rng(seed)
    T_WC = window_poses()
    T_SW = np.linalg.inv(T_WC[2])
    T_SC = T_SW @ T_WC
    X_W = np.c_[rng.uniform(-1, 2, n_pts), rng.uniform(3.0, 4.0, n_pts), rng.uniform(0, 2.5, n_pts)]
    pairs = []
    for off in (1, 2):
        for i in range(5 - off):
            j = i + off
            pc = []
            for k in (i, j):
                T_CW = np.linalg.inv(T_WC[k])
                p = X_W @ T_CW[:3, :3].T + T_CW[:3, 3]
                pc.append(p * scales_err[k])
            pi, pj = pc
            n_out = int(outlier_frac * n_pts)
            if n_out:
                bad = rng.choice(n_pts, n_out, replace=False)
                pj = pj.copy()
                pj[bad] *= rng.uniform(0.5, 1.6, (n_out, 1))   # wrong matches: wrong depth
            pairs.append(PairMatches(i, j, pi, pj))
    return pairs, T_SC


def _expected(scales_err):
    s = 1.0 / np.asarray(scales_err)
    return s / np.exp(np.mean(np.log(s)))


def test_recovers_injected_scales_up_to_geometric_mean():
    err = np.array([1.10, 0.95, 1.0, 1.06, 0.90])
    pairs, T_SC = _window_matches(err)
    res = solve_frame_scales(pairs, T_SC, prior_sigma=10.0)
    assert np.allclose(res.scales, _expected(err), rtol=2e-3)
    assert np.isclose(np.sum(np.log(res.scales)), 0.0, atol=1e-12)
    assert res.rms_after < 0.1 * res.rms_before


def test_outlier_matches_are_down_weighted():
    err = np.array([1.10, 0.95, 1.0, 1.06, 0.90])
    pairs, T_SC = _window_matches(err, outlier_frac=0.15, seed=3)
    robust = solve_frame_scales(pairs, T_SC, prior_sigma=10.0, rounds=8)
    one_round = solve_frame_scales(pairs, T_SC, prior_sigma=10.0, rounds=1)
    e_robust = np.abs(np.log(robust.scales / _expected(err))).max()
    e_plain = np.abs(np.log(one_round.scales / _expected(err))).max()
    assert e_robust < 0.01 < e_plain


def test_no_usable_pairs_leaves_unit_scales():
    pairs, T_SC = _window_matches(np.ones(5))
    few = [PairMatches(p.i, p.j, p.p_i[:5], p.p_j[:5]) for p in pairs]
    res = solve_frame_scales(few, T_SC, min_matches=20)
    assert np.array_equal(res.scales, np.ones(5)) and res.rounds == 0
