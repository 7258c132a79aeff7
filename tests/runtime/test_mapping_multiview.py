"""Multi-view rejection removes injected flying pixels and keeps the true surfaces."""
from __future__ import annotations

import numpy as np
from mapping_synth import H_TEST, K_TEST, W_TEST, render_room_depth, window_poses

from runtime.mapping.multiview import confidence_mask, reobserved, sample_grid
from runtime.mapping.placement import backproject


def test_flying_pixels_are_rejected_and_true_surfaces_kept():
    T_WC = window_poses()
    T_SC = np.linalg.inv(T_WC[2]) @ T_WC
    depths = np.stack([render_room_depth(T) for T in T_WC])
    rng = np.random.default_rng(0)
    noisy = depths * np.exp(rng.normal(0, 0.01, depths.shape))       # 1 % depth noise: true surface
    u, v = sample_grid(H_TEST, W_TEST, 2)
    src = np.repeat(np.arange(5), u.size)
    d = noisy[:, v, u].ravel()
    # flying pixels: 5 % of the samples of image 1 and 3 pulled 20-60 % towards the camera
    fly = np.zeros(d.size, bool)
    for img in (1, 3):
        idx = np.flatnonzero(src == img)
        pick = rng.choice(idx, idx.size // 20, replace=False)
        fly[pick] = True
        d[pick] *= rng.uniform(0.4, 0.8, pick.size)
    uu, vv = np.tile(u, 5), np.tile(v, 5)
    p_C = backproject(d, K_TEST, uu, vv)
    p_S = np.einsum("pij,pj->pi", T_SC[src, :3, :3], p_C) + T_SC[src, :3, 3]
    keep = reobserved(p_S, src, T_SC, noisy, K_TEST, 0.10)
    assert keep[fly].mean() < 0.02                 # flying pixels go
    assert keep[~fly].mean() > 0.97                # the true surface seen twice stays


def test_a_point_seen_by_one_image_only_is_rejected():
    T_WC = window_poses(2)
    T_SC = np.linalg.inv(T_WC[0]) @ T_WC
    depths = np.stack([render_room_depth(T) for T in T_WC])
    depths[1] = np.nan                              # the other image has no valid depth
    p = backproject(np.array([depths[0, 60, 80]]), K_TEST, np.array([80]), np.array([60]))
    assert not reobserved(p, np.array([0]), T_SC, depths, K_TEST)[0]


def test_confidence_mask_keeps_the_upper_percentiles():
    c = np.arange(1, 101, dtype=float)
    m = confidence_mask(c, 25.0)
    assert m.sum() == 75 and not m[:25].any()
