"""Multi-view rejection removes injected flying pixels and keeps the true surfaces."""
from __future__ import annotations

import numpy as np
from mapping_synth import H_TEST, K_TEST, W_TEST, look_at, render_room_depth, window_poses

from runtime.mapping.multiview import confidence_mask, multiview_test, sample_grid
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
    keep = multiview_test(p_S, src, T_SC, noisy, K_TEST, 0.10)[0]       # the paper's rule: agree
    assert keep[fly].mean() < 0.02                 # flying pixels go
    assert keep[~fly].mean() > 0.97                # the true surface seen twice stays


def test_a_point_seen_by_one_image_only_is_rejected():
    T_WC = window_poses(2)
    T_SC = np.linalg.inv(T_WC[0]) @ T_WC
    depths = np.stack([render_room_depth(T) for T in T_WC])
    depths[1] = np.nan                              # the other image has no valid depth
    p = backproject(np.array([depths[0, 60, 80]]), K_TEST, np.array([80]), np.array([60]))
    agree, seen = multiview_test(p, np.array([0]), T_SC, depths, K_TEST)
    assert not agree[0] and not seen[0]             # neither confirmed nor contradicted: unseen


def test_seen_separates_contradicted_from_unverifiable_points():
    """A point is `seen` when another image holds a valid depth where it projects: a flying pixel in
    view of the others is seen and contradicted; a point outside every other image, or behind every
    other camera, is unseen; a true point in view is seen and confirmed."""
    T_WC = window_poses(3)
    T_WC[2] = look_at(np.array([0.3, 0.0, 1.0]), np.array([0.3, -4.0, 1.2]))  # image 2 looks backwards
    T_SC = np.linalg.inv(T_WC[0]) @ T_WC
    depths = np.stack([render_room_depth(T) for T in T_WC])
    px = np.array([[80, 60], [80, 60], [2, 60]])         # centre, centre (flying), left border
    z = depths[0, px[:, 1], px[:, 0]] * np.array([1.0, 0.6, 1.0])
    p = backproject(z, K_TEST, px[:, 0], px[:, 1])
    # the left-border pixel of image 0 lies outside image 1 (shifted right) and behind image 2
    p_C1 = (np.linalg.inv(T_SC[1]) @ np.r_[p[2], 1.0])[:3]
    assert K_TEST[0, 0] * p_C1[0] / p_C1[2] + K_TEST[0, 2] < -0.5
    agree, seen = multiview_test(p, np.zeros(3, int), T_SC, depths, K_TEST)
    np.testing.assert_array_equal(agree, [True, False, False])
    np.testing.assert_array_equal(seen, [True, True, False])


def test_confidence_mask_keeps_the_upper_percentiles():
    c = np.arange(1, 101, dtype=float)
    m = confidence_mask(c, 25.0)
    assert m.sum() == 75 and not m[:25].any()
