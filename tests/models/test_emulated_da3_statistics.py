"""Emulated DA3: the error statistics of its outputs match its parameters.

Each test switches on one error mode (the others at zero), runs enough calls on the closed-form
box room, and compares the measured statistic of output-vs-truth with the parameter, within a
sampling tolerance of about 3-4 standard errors.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.stats import spearmanr

from models.emulated_da3 import BoxRoom, EmulatedDA3, make_params
from models.emulated_da3.depth_errors import DenseErrorLevels, confidence, corrupt_view, flying_band
from runtime.events import Frame

W, H = 96, 64
K_RECT = np.array([[70.0, 0.0, 47.5], [0.0, 70.0, 31.5], [0.0, 0.0, 1.0]])
DENSE_OFF = dict(
    image_log_scale_sigma=0.0,
    image_log_scale_sigma_cond=0.0,
    window_log_scale_sigma_cond=0.0,
    window_outlier_prob=0.0,
    field_sigma=0.0,
    field_sigma_cond=0.0,
    noise_sigma=0.0,
    flying_fraction=0.0,
    reflective_prob=0.0,
    cond_centre_noise_frac=0.0,
    centre_floor_frac=0.0,
)
POSE_OFF = dict(
    rotation_error_median_deg=0.0,
    rotation_error_frac=0.0,
    translation_direction_median_deg=0.0,
    translation_norm_log_sigma=0.0,
    centre_floor_frac=0.0,
)


def window(n: int = 5, dt_s: float = 0.2):
    ts = [int(round(i * dt_s * 1e9)) for i in range(n)]
    return [Frame(t, np.zeros((H, W), np.uint8)) for t in ts], ts


def truth(room: BoxRoom, ts):
    d = np.stack([room.render_view(t, K_RECT, W, H).depth for t in ts]).astype(np.float64)
    T_CW = np.stack([np.linalg.inv(room.T_WC(t)) for t in ts])
    return d, T_CW


def log_ratio(pred: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """(N,H,W) log(pred / truth), NaN where the truth has no surface."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(np.isfinite(depth), np.log(pred / depth), np.nan)


def rot_angle(R: np.ndarray) -> np.ndarray:
    return np.arccos(np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1, 1))


# ---------------------------------------------------------------------------- scale
def test_unconditioned_global_and_per_image_log_scale():
    p = make_params("base")
    room = BoxRoom()
    frames, ts = window(5)
    depth, _ = truth(room, ts)
    model = EmulatedDA3(
        room, K_RECT, W, H, seed=21, **{**DENSE_OFF, "image_log_scale_sigma": p.image_log_scale_sigma}
    )
    per_image, per_call = [], []
    for _ in range(40):
        r = np.nanmedian(log_ratio(model.predict(frames).depth, depth).reshape(5, -1), axis=1)
        per_image.append(r - r.mean())
        per_call.append(r.mean())
    # within-call deviations: std * sqrt(N/(N-1)) estimates the per-image sigma (160 dof)
    est = np.std(np.concatenate(per_image)) * np.sqrt(5 / 4)
    assert est == pytest.approx(p.image_log_scale_sigma, rel=0.2)
    # the call scale is random (up to scale): log-std = sqrt(global^2 + image^2/N)
    expect = np.hypot(p.global_log_scale_sigma, p.image_log_scale_sigma / np.sqrt(5))
    assert np.std(per_call, ddof=1) == pytest.approx(expect, rel=0.3)
    # and its level is DA3's normalisation (mean point distance 1), not metres
    assert abs(np.mean(per_call) - np.log(1 / 4.0)) < 0.6


def test_conditioned_window_log_scale_and_outliers_show_in_the_reported_scale():
    room = BoxRoom()
    frames, ts = window(3)
    depth, T_CW = truth(room, ts)
    sigma, p_out = 0.03, 0.2
    model = EmulatedDA3(
        room,
        K_RECT,
        W,
        H,
        seed=22,
        **{**DENSE_OFF, "window_log_scale_sigma_cond": sigma, "window_outlier_prob": p_out},
    )
    K = np.tile(K_RECT, (3, 1, 1))
    depth_log, gate_log = [], []
    for _ in range(150):
        pred = model.predict(frames, K, T_CW)
        depth_log.append(np.nanmedian(log_ratio(pred.depth, depth)))
        gate_log.append(pred.info["log_scale_normalised"])
    depth_log, gate_log = np.array(depth_log), np.array(gate_log)
    outlier = np.abs(gate_log) > 0.3  # the mapping gate |log s| <= 0.3
    assert outlier.mean() == pytest.approx(p_out, abs=0.1)
    assert np.all((np.abs(gate_log[outlier]) >= 0.3) & (np.abs(gate_log[outlier]) <= 0.7))
    np.testing.assert_allclose(gate_log[~outlier], 0.0, atol=1e-9)  # exact inputs, no centre noise
    # inliers: the residual window scale of the metric depth is N(0, sigma)
    assert np.std(depth_log[~outlier]) == pytest.approx(sigma, rel=0.25)
    assert abs(np.mean(depth_log[~outlier])) < 4 * sigma / np.sqrt((~outlier).sum())
    # outliers: the wrapper divided by the failed camera scale, so depth is off by -log s
    resid = depth_log[outlier] + gate_log[outlier]
    assert np.std(resid) == pytest.approx(sigma, rel=0.5)


# ---------------------------------------------------------------------------- dense errors
def test_smooth_relative_field_magnitude_and_smoothness():
    p = make_params("base")
    room = BoxRoom()
    frames, ts = window(5)
    depth, T_CW = truth(room, ts)
    flat = dict(low_texture_field_gain=1.0, far_min_m=50.0)  # no texture or far-range gain
    K = np.tile(K_RECT, (5, 1, 1))
    for cond, sigma in [(False, p.field_sigma), (True, p.field_sigma_cond)]:
        over = {**DENSE_OFF, **flat, **({"field_sigma_cond": sigma} if cond else {"field_sigma": sigma})}
        model = EmulatedDA3(room, K_RECT, W, H, seed=23, **over)
        vals, dx = [], []
        for _ in range(12):
            r = log_ratio(
                model.predict(frames, K, T_CW).depth if cond else model.predict(frames).depth, depth
            )
            if not cond:
                r = r - np.nanmean(r)  # remove the call's global scale
            vals.append(r[np.isfinite(r)])
            dx.append((r[:, :, 1:] - r[:, :, :-1])[np.isfinite(r[:, :, 1:] - r[:, :, :-1])])
        est = np.sqrt(np.mean(np.concatenate(vals) ** 2))
        assert est == pytest.approx(sigma, rel=0.25), cond
        # smooth: neighbouring pixels differ by far less than the field itself
        assert np.std(np.concatenate(dx)) < 0.2 * sigma


def test_noise_grows_with_depth_and_on_low_texture():
    p = make_params("base", far_min_m=4.0, far_max_m=4.0)  # d_far = 4 m
    room = BoxRoom()
    frames, ts = window(5)
    depth, T_CW = truth(room, ts)
    K = np.tile(K_RECT, (5, 1, 1))
    over = {**DENSE_OFF, "noise_sigma": p.noise_sigma, "far_min_m": 4.0, "far_max_m": 4.0}
    model = EmulatedDA3(room, K_RECT, W, H, seed=24, **over)
    r = np.stack([log_ratio(model.predict(frames, K, T_CW).depth, depth) for _ in range(4)])
    d = np.broadcast_to(depth, r.shape)
    sid = np.broadcast_to(np.stack([room.render_view(t, K_RECT, W, H).surface_id for t in ts]), r.shape)
    textured = (sid != 3) & np.isfinite(d)
    near = textured & (d < 4.0)
    far = textured & (d > 4.5)
    # constant relative noise up to d_far, growing as d / d_far beyond it
    assert np.std(r[near]) == pytest.approx(p.noise_sigma, rel=0.1)
    assert np.std(r[far] / (d[far] / 4.0)) == pytest.approx(p.noise_sigma, rel=0.1)
    # so the absolute error grows with depth (faster than linearly beyond d_far)
    abs_err = np.abs(np.expm1(r)) * d
    b1 = near & (d < 3.0)
    b2 = far & (d > 6.0)
    assert np.mean(abs_err[b2]) / np.mean(abs_err[b1]) > (np.mean(d[b2]) / np.mean(d[b1])) * 1.3
    # the bare wall (texture 0.005 < threshold): noise x (1 + (gain - 1) w), on top of the far-range gain
    bare = (sid == 3) & np.isfinite(d)
    q = np.maximum(1.0, d[bare] / 4.0)
    w = 1.0 - 0.005 / p.low_texture_threshold
    gain = 1.0 + (p.low_texture_noise_gain - 1.0) * w
    assert gain > 1.3
    assert np.std(r[bare] / q) == pytest.approx(p.noise_sigma * gain, rel=0.12)


def test_flying_pixels_sit_in_the_discontinuity_band_with_the_stated_share():
    p = make_params("base")
    room = BoxRoom()
    v = room.render_view(0, K_RECT, W, H)
    d = v.depth.astype(np.float64)
    rng = np.random.default_rng(25)
    levels = DenseErrorLevels(0.0, 0.0, 0.0)
    fly = band = 0
    for _ in range(10):
        cv = corrupt_view(
            rng,
            d,
            d,
            v.texture,
            v.reflective,
            v.dynamic,
            v.surface_id,
            make_params("base", reflective_prob=0.0),
            levels,
            3.0,
        )
        fly += cv.flying.sum()
        band += cv.band.sum()
        changed = np.abs(cv.depth - np.where(cv.sky, cv.depth, d)) > 1e-9
        assert not (changed & ~cv.flying).any()  # only flying pixels move
    share = fly / band
    assert share == pytest.approx(p.flying_fraction, abs=4 * np.sqrt(0.25 / band))
    # the band is where the truth jumps: every 4-neighbour step > 10% between two surfaces is in
    # it (oblique planes also step > 10% near the horizon, and must not count), and a band pixel
    # is never farther than 1 px from a surface change (occlusion edge or crease)
    sid = v.surface_id
    dd = np.where(np.isfinite(d), d, 2 * np.nanmax(d[np.isfinite(d)]))
    b, near, far = flying_band(dd, 1, p.flying_jump_rel, sid)
    step = np.zeros_like(b)
    jump = (np.abs(np.log(dd[:, 1:] / dd[:, :-1])) > 0.1) & (sid[:, 1:] != sid[:, :-1])
    step[:, 1:] |= jump
    step[:, :-1] |= jump
    assert step.sum() > 50 and b[step].all()
    boundary = np.zeros_like(b)
    boundary[:, 1:] |= sid[:, 1:] != sid[:, :-1]
    boundary[:, :-1] |= sid[:, 1:] != sid[:, :-1]
    boundary[1:] |= sid[1:] != sid[:-1]
    boundary[:-1] |= sid[1:] != sid[:-1]
    near_boundary = cv2.dilate(boundary.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert not (b & ~near_boundary).any()
    assert (near <= d).all() and (far >= np.where(np.isfinite(d), d, 0)).all()


def test_confidence_tracks_the_error():
    room = BoxRoom()
    frames, ts = window(5)
    depth, T_CW = truth(room, ts)
    model = EmulatedDA3(room, K_RECT, W, H, preset="base", seed=26)
    K = np.tile(K_RECT, (5, 1, 1))
    rho, levels = [], []
    for cond in (True, True, False):
        pred = model.predict(frames, K, T_CW) if cond else model.predict(frames)
        m = np.isfinite(depth)
        est = pred.depth[m] / np.median(pred.depth[m] / depth[m])  # uncond: back to metres
        rho.append(spearmanr(pred.conf[m], np.abs(est - depth[m]))[0])
        levels.append(np.median(pred.conf))
        assert (pred.conf >= 1).all()
        assert np.median(pred.conf[~m]) < np.percentile(pred.conf[m], 10)  # no surface: least confident
    assert all(-0.8 < r < -0.3 for r in rho), rho  # target about -0.5 (-0.47 on the simulator's rooms)
    assert len(set(np.round(levels, 6))) == 3  # the level changes per call


def test_flying_pixels_fall_below_the_25th_confidence_percentile():
    p = make_params("base")
    room = BoxRoom()
    v = room.render_view(0, K_RECT, W, H)
    d = v.depth.astype(np.float64)
    rng = np.random.default_rng(27)
    below = []
    for _ in range(5):
        cv = corrupt_view(
            rng,
            d,
            d,
            v.texture,
            v.reflective,
            v.dynamic,
            v.surface_id,
            p,
            DenseErrorLevels(p.image_log_scale_sigma_cond, p.field_sigma_cond, p.noise_sigma),
            3.0,
        )
        conf = confidence(rng, cv.expected_error[None], p)[0]
        below.append(np.mean(conf[cv.flying] < np.percentile(conf, 25)))
    assert np.mean(below) >= 0.65


def test_reflective_surfaces_show_a_depth_behind_the_mirror():
    room = BoxRoom()
    frames, ts = window(2)
    depth, T_CW = truth(room, ts)
    mirror = np.stack([room.render_view(t, K_RECT, W, H).reflective for t in ts])
    model = EmulatedDA3(room, K_RECT, W, H, seed=28, **{**DENSE_OFF, "reflective_prob": 0.5})
    K = np.tile(K_RECT, (2, 1, 1))
    hits = []
    for _ in range(40):
        r = log_ratio(model.predict(frames, K, T_CW).depth, depth)
        assert np.allclose(r[~mirror & np.isfinite(r)], 0.0, atol=1e-6)  # only the mirror is affected
        g = np.exp(r[0][mirror[0]])
        hits.append(bool(np.all(g > 1.0 + 1e-6)))
        if hits[-1]:
            assert np.all((g >= 1.3 - 1e-6) & (g <= 2.0 + 1e-6)) and np.ptp(g) < 1e-6
    assert np.mean(hits) == pytest.approx(0.5, abs=0.25)


def test_small_baseline_halves_the_conditioning_gain():
    p = make_params("base")
    room = BoxRoom(velocity=(0.0, 0.1, 0.0))  # 2 cm between frames < 0.1 m
    frames, ts = window(5)
    depth, T_CW = truth(room, ts)
    over = {
        **DENSE_OFF,
        "field_sigma_cond": p.field_sigma_cond,
        "field_sigma": p.field_sigma,
        "low_texture_field_gain": 1.0,
        "far_min_m": 50.0,
    }
    model = EmulatedDA3(room, K_RECT, W, H, seed=29, **over)
    K = np.tile(K_RECT, (5, 1, 1))
    vals = [log_ratio(model.predict(frames, K, T_CW).depth, depth) for _ in range(12)]
    est = np.sqrt(np.nanmean(np.concatenate([v[np.isfinite(v)] for v in vals]) ** 2))
    assert est == pytest.approx(p.field_sigma_cond + 0.5 * (p.field_sigma - p.field_sigma_cond), rel=0.25)


# ---------------------------------------------------------------------------- poses and intrinsics
def _relative_truth(room: BoxRoom, ts):
    T_WC = np.stack([room.T_WC(t) for t in ts])
    return np.linalg.inv(T_WC[0]) @ T_WC  # T_C0Ci


def test_unconditioned_rotation_error_median():
    p = make_params("base")
    room = BoxRoom(velocity=(0.0, 1.5, 0.2))  # larger relative rotations: the proportional term shows
    frames, ts = window(5)
    T_rel = _relative_truth(room, ts)
    model = EmulatedDA3(room, K_RECT, W, H, seed=30, **{**DENSE_OFF, "translation_direction_median_deg": 0.0})
    norm = []
    for _ in range(40):
        T_pred = np.linalg.inv(model.predict(frames).T_CW)  # T_C0Ci
        err = np.rad2deg(rot_angle(T_pred[1:, :3, :3] @ np.transpose(T_rel[1:, :3, :3], (0, 2, 1))))
        med = p.rotation_error_median_deg + p.rotation_error_frac * np.rad2deg(rot_angle(T_rel[1:, :3, :3]))
        norm.append(err / med)
    norm = np.concatenate(norm)  # 160 samples of exp(N(0, 0.6))
    assert np.median(norm) == pytest.approx(1.0, rel=0.2)
    assert np.std(np.log(norm)) == pytest.approx(p.rotation_error_log_sigma, rel=0.2)


def test_unconditioned_translation_direction_error_distribution():
    p = make_params("base")
    room = BoxRoom()
    frames, ts = window(5)
    p_true = _relative_truth(room, ts)[1:, :3, 3]
    model = EmulatedDA3(room, K_RECT, W, H, seed=31, **{**DENSE_OFF, "centre_floor_frac": 0.0})
    ang = []
    for _ in range(40):
        p_pred = np.linalg.inv(model.predict(frames).T_CW)[1:, :3, 3]
        c = np.sum(p_pred * p_true, 1) / np.linalg.norm(p_pred, axis=1) / np.linalg.norm(p_true, axis=1)
        ang.append(np.rad2deg(np.arccos(np.clip(c, -1, 1))))
    ang = np.concatenate(ang)
    assert np.median(ang) == pytest.approx(p.translation_direction_median_deg, rel=0.2)
    assert np.std(np.log(ang)) == pytest.approx(p.translation_direction_log_sigma, rel=0.2)
    assert np.percentile(ang, 90) > 2.5 * p.translation_direction_median_deg  # heavy tail


def test_unconditioned_camera_centre_floor_and_length_error():
    p = make_params("small")
    room = BoxRoom()
    frames, ts = window(5)
    depth, _ = truth(room, ts)
    p_true = _relative_truth(room, ts)[1:, :3, 3]
    median_depth = np.median(depth[np.isfinite(depth)])
    # floor only: the centre error is isotropic N(0, (floor * median depth)^2) per axis
    over = {**DENSE_OFF, **POSE_OFF, "centre_floor_frac": p.centre_floor_frac}
    model = EmulatedDA3(room, K_RECT, W, H, preset="small", seed=32, **over)
    errs = []
    for _ in range(30):
        pred = model.predict(frames)
        g = np.nanmedian(log_ratio(pred.depth, depth))  # the call's scale (no depth errors)
        errs.append(np.linalg.inv(pred.T_CW)[1:, :3, 3] / np.exp(g) - p_true)
    errs = np.concatenate(errs)
    assert np.std(errs, axis=0) == pytest.approx([p.centre_floor_frac * median_depth] * 3, rel=0.3)
    # length only
    over = {**DENSE_OFF, **POSE_OFF, "translation_norm_log_sigma": p.translation_norm_log_sigma}
    model = EmulatedDA3(room, K_RECT, W, H, preset="small", seed=33, **over)
    lr = []
    for _ in range(30):
        pred = model.predict(frames)
        g = np.nanmedian(log_ratio(pred.depth, depth))
        lr.append(
            np.log(
                np.linalg.norm(np.linalg.inv(pred.T_CW)[1:, :3, 3], axis=1)
                / np.exp(g)
                / np.linalg.norm(p_true, axis=1)
            )
        )
    assert np.std(np.concatenate(lr)) == pytest.approx(p.translation_norm_log_sigma, rel=0.2)


def test_unconditioned_focal_error():
    p = make_params("large")
    room = BoxRoom()
    frames, _ = window(8)
    model = EmulatedDA3(room, K_RECT, W, H, preset="large", seed=34, **DENSE_OFF)
    f = np.concatenate([np.log(model.predict(frames).K[:, 0, 0] / K_RECT[0, 0]) for _ in range(20)])
    assert np.std(f) == pytest.approx(p.focal_log_sigma, rel=0.2)
    assert abs(np.mean(f)) < 4 * p.focal_log_sigma / np.sqrt(len(f))


def test_dynamic_objects_raise_the_pose_error():
    room_static, room_dyn = BoxRoom(), BoxRoom(dynamic_box=True)
    frames, ts = window(5)
    p_true = _relative_truth(room_static, ts)[1:, :3, 3]
    frac = np.mean([room_dyn.render_view(t, K_RECT, W, H).dynamic.mean() for t in ts])
    med = []
    for room in (room_static, room_dyn):
        model = EmulatedDA3(room, K_RECT, W, H, seed=35, **{**DENSE_OFF, "centre_floor_frac": 0.0})
        ang = []
        for _ in range(30):
            p_pred = np.linalg.inv(model.predict(frames).T_CW)[1:, :3, 3]
            c = np.sum(p_pred * p_true, 1) / np.linalg.norm(p_pred, axis=1) / np.linalg.norm(p_true, axis=1)
            ang.append(np.arccos(np.clip(c, -1, 1)))
        med.append(np.median(np.concatenate(ang)))
    gain = 1 + make_params().dynamic_pose_gain * frac
    assert med[1] / med[0] == pytest.approx(gain, rel=0.3)
