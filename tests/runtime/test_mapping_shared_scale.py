"""kappa_ab / sigma_ab (paper eq. shared) against a synthetic known depth ratio."""
from __future__ import annotations

import numpy as np
from mapping_synth import K_TEST, render_room_depth, window_poses

from runtime.mapping.placement import backproject
from runtime.mapping.shared_scale import kappa_sigma, overlap_link, shared_link


def test_shared_images_give_the_known_log_ratio():
    T_WC = window_poses()
    rng = np.random.default_rng(0)
    da = {t: render_room_depth(T_WC[k]) for k, t in enumerate((10, 20))}
    # submap b's depths of the same images are 8 % larger (lambda_b - lambda_a = -log 1.08), with noise
    db = {t: d * 1.08 * np.exp(rng.normal(0, 0.02, d.shape)) for t, d in da.items()}
    db[30] = da[10]                                           # not shared: ignored
    link = shared_link(0, 1, da, db)
    assert link.method == "shared" and link.n_images == 2
    assert np.isclose(link.kappa, -np.log(1.08), atol=2e-3)
    assert link.sigma == 0.03                                 # consistent images: the floor


def test_sigma_is_half_the_spread_of_the_image_ratios():
    kappa, sigma = kappa_sigma([0.10, -0.02])
    assert np.isclose(kappa, -0.04) and np.isclose(sigma, 0.06)


def test_no_shared_image_uses_the_projected_overlap():
    T_WC = window_poses()
    d_a = render_room_depth(T_WC[1])
    d_b = render_room_depth(T_WC[3])
    v, u = np.mgrid[0:120:2, 0:160:2]
    pts_C = backproject(d_b[v, u].ravel() * 0.9, K_TEST, u.ravel(), v.ravel())   # b's depths 10 % short
    pts_O = pts_C @ T_WC[3][:3, :3].T + T_WC[3][:3, 3]
    link = overlap_link(0, 1, pts_O, T_WC[1], d_a, K_TEST)
    assert link.method == "overlap"
    # b's surface lies 10 % nearer its own camera; seen from a nearby camera the ratio is close to it
    assert abs(link.kappa - (-np.log(0.9))) < 0.03
    assert shared_link(0, 1, {1: d_a}, {2: d_b}) is None
