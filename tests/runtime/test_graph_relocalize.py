"""Localising a map session in another (runtime/graph/relocalize.py) on synthetic views of one room:
the transform is known in closed form, the views are projections of textured wall points."""
from __future__ import annotations

import numpy as np
import pytest

from models.matcher.features import Features
from models.matcher.matcher import match_stored
from runtime.graph.place_consensus import Hypothesis, consensus, yaw_translation_fit
from runtime.graph.relocalize import AlignConfig, PlaceView, PriorMapLocalizer, align_sessions
from runtime.graph.revisits import RevisitView
from runtime.graph.vocabulary import Vocabulary

K = np.array([[380.0, 0.0, 376.0], [0.0, 380.0, 240.0], [0.0, 0.0, 1.0]])
SIZE = (752, 480)


def _rz(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _pose(R: np.ndarray, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def _room(seed: int, n: int = 3000) -> tuple[np.ndarray, np.ndarray]:
    """Points on the four walls of an 8 x 6 x 3 m room (world frame, z up) and a descriptor each.

    Textures as a vocabulary sees them: each 2 m stretch of wall draws its points' appearance from 6 of
    60 texture prototypes (descriptor = 0.6 prototype + 0.8 a point's own part), so views of different
    walls hold different words while every point stays distinct for matching."""
    rng = np.random.default_rng(seed)
    wall = rng.integers(0, 4, n)
    u, z = rng.uniform(0, 1, n), rng.uniform(0.2, 2.8, n)
    x = np.where(wall == 0, -4.0, np.where(wall == 1, 4.0, -4.0 + 8.0 * u))
    y = np.where(wall == 2, -3.0, np.where(wall == 3, 3.0, -3.0 + 6.0 * u))
    region = wall * 4 + np.minimum((u * np.where(wall < 2, 6.0, 8.0) / 2.0).astype(int), 3)
    prototypes = _unit(rng.normal(size=(60, 64)))
    region_words = np.stack([rng.choice(60, 6, replace=False) for _ in range(16)])
    proto = prototypes[region_words[region, rng.integers(0, 6, n)]]
    desc = _unit(0.6 * proto + 0.8 * _unit(rng.normal(size=(n, 64))))
    return np.column_stack([x, y, z]), desc


def _camera_pose_W(yaw_deg: float, position) -> np.ndarray:
    """T_WC of a level camera (z forward, x right, y down) looking along world yaw_deg."""
    R_look = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # camera axes in a yaw-0 body
    return _pose(_rz(yaw_deg) @ R_look, position)


def _view(points_W, desc, T_WC, rng, depth_error=0.02) -> tuple[Features, RevisitView]:
    T_CW = np.linalg.inv(T_WC)
    p = points_W @ T_CW[:3, :3].T + T_CW[:3, 3]
    uv = p @ K.T
    ok = p[:, 2] > 0.3
    uv = uv[:, :2] / np.where(ok, p[:, 2], 1.0)[:, None]
    ok &= (uv[:, 0] > 0) & (uv[:, 0] < SIZE[0] - 1) & (uv[:, 1] > 0) & (uv[:, 1] < SIZE[1] - 1)
    idx = np.flatnonzero(ok)
    kpts = (uv[idx] + rng.normal(0, 0.3, (len(idx), 2))).astype(np.float32)
    d = desc[idx] + rng.normal(0, 0.05, (len(idx), desc.shape[1]))
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    depth = p[idx, 2] * (1.0 + depth_error * rng.normal(size=len(idx)))
    return (Features(kpts, np.ones(len(idx), np.float32), d, SIZE, None),
            RevisitView(K, kpts.astype(np.float64), depth, SIZE))


def _session(points_W, desc, T_MW, yaws, positions, seed) -> list[PlaceView]:
    rng = np.random.default_rng(seed)
    out = []
    for i, (yaw, pos) in enumerate(zip(yaws, positions, strict=True)):
        T_WC = _camera_pose_W(yaw, pos)
        f, v = _view(points_W, desc, T_WC, rng)
        out.append(PlaceView(i, T_MW @ T_WC, f, v))
    return out


def _match(fa: Features, fb: Features):
    m = match_stored(fa, fb)
    return m.idx_a, m.idx_b


def _sessions(T_PW, T_NW, new_room_seed=1):
    pts, desc = _room(1)
    yaws = np.arange(0, 360, 30.0)
    ring = [(1.5 * np.cos(np.radians(a)), 1.0 * np.sin(np.radians(a)), 1.4) for a in yaws]
    prior = _session(pts, desc, T_PW, yaws, ring, seed=2)
    if new_room_seed != 1:
        pts, desc = _room(new_room_seed)
    ring_new = [(x + 0.3, y - 0.2, z + 0.1) for x, y, z in ring]
    new = _session(pts, desc, T_NW, yaws[::2] + 8.0, ring_new[::2], seed=3)
    return prior, new


def test_align_sessions_recovers_the_yaw_and_translation_between_two_map_frames():
    T_PW = _pose(_rz(-25.0), [0.4, 1.1, 0.0])
    T_NW = _pose(_rz(40.0), [1.5, -2.0, 0.3])
    prior, new = _sessions(T_PW, T_NW)
    res = align_sessions(prior, new, _match, AlignConfig(words=64, candidates_per_view=1))
    assert res.localized, res.reason                       # the vocabulary's first choice is right
    assert res.attempts == len(new) and len(res.hypotheses) == len(new)
    T_true = T_PW @ np.linalg.inv(T_NW)
    dyaw = np.degrees(np.arctan2(*(res.T_PN[:3, :3] @ np.linalg.inv(T_true[:3, :3]))[[1, 0], [0, 0]]))
    assert abs(dyaw) < 0.2
    assert np.linalg.norm(res.T_PN[:3, 3] - T_true[:3, 3]) < 0.03
    assert res.rms_m < 0.2
    agreeing_views = {res.hypotheses[i].new for i in res.agreeing}
    assert len(agreeing_views) >= 3
    d = res.as_dict()
    assert d["localized"] and d["verified"] == len(res.hypotheses) and d["attempts"] >= d["verified"]


def test_a_session_of_another_place_is_not_localized():
    prior, new = _sessions(np.eye(4), np.eye(4), new_room_seed=7)
    res = align_sessions(prior, new, _match, AlignConfig(words=64))
    assert not res.localized and res.T_PN is None
    assert res.attempts > 0 and sum(res.rejected.values()) == res.attempts - len(res.hypotheses)


def test_a_frame_that_is_not_gravity_aligned_is_refused_by_the_tilt_check():
    c, s = np.cos(0.2), np.sin(0.2)
    tilt = _pose(np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]), [0.0, 0.0, 0.0])  # 11.5 deg of roll
    prior, new = _sessions(np.eye(4), tilt)
    res = align_sessions(prior, new, _match, AlignConfig(words=64))
    assert not res.localized
    assert res.rejected["tilt"] > 0 and not res.hypotheses
    res_loose = align_sessions(prior, new, _match, AlignConfig(words=64, max_tilt_deg=15.0))
    assert res_loose.hypotheses                                          # the same pairs, tilt allowed


def _hyp(new: int, yaw: float, t) -> Hypothesis:
    return Hypothesis(0, new, _pose(_rz(yaw), t), yaw, 0.0, 40, 0.05, np.zeros((2, 3)), np.zeros((2, 3)))


def test_consensus_needs_enough_distinct_new_views_and_refuses_two_places():
    cfg = AlignConfig(min_views=3)
    one_place = [_hyp(1, 10.0, [1, 0, 0]), _hyp(2, 10.5, [1.1, 0, 0]), _hyp(3, 9.8, [1, 0.1, 0]),
                 _hyp(4, 60.0, [4, 4, 0])]
    group, reason = consensus(one_place, cfg)
    assert sorted(group) == [0, 1, 2] and reason == "localized"
    same_view = [_hyp(1, 10.0, [1, 0, 0]), _hyp(1, 10.2, [1, 0, 0]), _hyp(2, 10.1, [1, 0, 0])]
    assert consensus(same_view, cfg)[0] == []                            # two new views only
    two_places = one_place[:3] + [_hyp(5, 60.0, [4, 4, 0]), _hyp(6, 60.3, [4, 4.1, 0]),
                                  _hyp(7, 59.9, [4.1, 4, 0])]
    group, reason = consensus(two_places, cfg)
    assert group == [] and reason.startswith("ambiguous")
    assert consensus([], cfg) == ([], "no candidate pair passed verification")


def test_yaw_translation_fit_is_the_closed_form_least_squares():
    rng = np.random.default_rng(4)
    x_N = rng.normal(size=(50, 3)) * 3
    T = _pose(_rz(123.0), [2.0, -1.0, 0.5])
    x_P = x_N @ T[:3, :3].T + T[:3, 3]
    assert np.allclose(yaw_translation_fit(x_P, x_N), T, atol=1e-9)
    noisy = x_P + rng.normal(0, 0.05, x_P.shape)
    fit = yaw_translation_fit(noisy, x_N)
    cost = np.sum((noisy - (x_N @ fit[:3, :3].T + fit[:3, 3])) ** 2)
    for dyaw in (-0.5, 0.5):                                  # a nearby yaw (translation refitted) costs more
        R = _rz(dyaw) @ fit[:3, :3]
        t = (noisy - x_N @ R.T).mean(axis=0)
        assert np.sum((noisy - (x_N @ R.T + t)) ** 2) > cost


def test_the_vocabulary_ranks_a_view_of_the_same_wall_first():
    pts, desc = _room(1)
    rng = np.random.default_rng(5)
    views = [_view(pts, desc, _camera_pose_W(yaw, (0, 0, 1.4)), rng)[0] for yaw in (0, 90, 180, 270)]
    voc = Vocabulary.train([v.desc for v in views], words=64)
    H = np.stack([voc.histogram(v.desc) for v in views])
    query = _view(pts, desc, _camera_pose_W(95.0, (0.3, 0.2, 1.4)), rng)[0]
    assert int(np.argmax(H @ voc.histogram(query.desc))) == 1
    assert np.allclose(np.linalg.norm(H, axis=1), 1.0, atol=1e-5)


def test_align_config_refuses_nonsense():
    with pytest.raises(ValueError, match="min_views"):
        AlignConfig(min_views=0)
    with pytest.raises(ValueError, match="agree_m"):
        AlignConfig(agree_m=float("nan"))


def test_the_localizer_narrows_its_search_once_localised_and_bounds_its_hypotheses():
    T_PW, T_NW = _pose(_rz(-25.0), [0.4, 1.1, 0.0]), _pose(_rz(40.0), [1.5, -2.0, 0.3])
    prior, new = _sessions(T_PW, T_NW)
    loc = PriorMapLocalizer(prior, _match, AlignConfig(words=64), max_hypotheses=8)
    changed = [loc.add_view(b, segment=2) for b in new]
    assert loc.T_PN(2) is not None and loc.T_PN(0) is None and changed.count(True) >= 1
    assert loc.segment_versions() == {2: loc.version} and loc.segments() == [2]
    assert len(loc.alignment(2).hypotheses) == 8 and loc.hypotheses_dropped > 0
    # localised: candidates only within the revisit radius of where the transform puts the view
    far = PlaceView(99, T_NW @ _camera_pose_W(0.0, (40.0, 0.0, 1.4)), new[0].features, new[0].view)
    near, fallback = loc._candidates(far, 2, search_near=True)
    assert near == [] and len(fallback) == loc.cfg.candidates_per_view   # tried only if nothing near verifies
    near, fallback = loc._candidates(far, 2, search_near=False)
    assert len(near) == loc.cfg.candidates_per_view and fallback == []


def test_prior_frame_publishes_nothing_before_localisation_then_the_transform_at_once():
    from types import SimpleNamespace

    from runtime.graph.prior_frame import PriorFrame

    T_PW, T_NW = _pose(_rz(-25.0), [0.4, 1.1, 0.0]), _pose(_rz(40.0), [1.5, -2.0, 0.3])
    prior, new = _sessions(T_PW, T_NW)
    pf = PriorFrame(PriorMapLocalizer(prior, _match, AlignConfig(words=64)), "prior")
    T_MI = _pose(_rz(10.0), [1.0, 2.0, 0.5])
    t = 1_000_000_000
    t_loc, T_first = None, None
    for k, b in enumerate(new):
        before = pf.localizer.T_PN(0) is None
        pf.on_submap(SimpleNamespace(index=b.index, T_MS=b.T_MS, view=(b.features, b.view), segment=0))
        pf.update(t + k * 10**9)
        if before and pf.localizer.T_PN(0) is not None:
            t_loc, T_first = t + k * 10**9, pf.localizer.T_PN(0)
    assert t_loc is not None
    assert pf.pose(0, t_loc - 1, T_MI) is None                     # before: no prior-frame pose
    assert np.array_equal(pf.pose(0, t_loc, T_MI), T_first @ T_MI)  # the first transform applies at once
    T_true = T_PW @ np.linalg.inv(T_NW)
    assert np.allclose(pf.pose(0, t_loc + 10**10, T_MI), T_true @ T_MI, atol=0.03)
    mask, T_PI = pf.causal(0, np.array([t_loc - 1, t_loc + 10**10]), np.stack([T_MI, T_MI]))
    assert mask.tolist() == [False, True] and T_PI.shape == (1, 4, 4)
    assert pf.final(0, T_MI[None])[0] == pytest.approx(pf.localizer.T_PN(0) @ T_MI)
    assert pf.final(1, T_MI[None]) is None and pf.pose(1, t_loc, T_MI) is None
    pf.on_submap(SimpleNamespace(index=50, T_MS=np.eye(4), view=None, segment=0))
    rep = pf.report()
    assert rep["submaps_without_view"] == 1 and rep["segments"]["0"]["localized"]
    assert rep["segments"]["0"]["localized_at_t_ns"] == t_loc


def test_agreement_is_judged_where_the_views_are_not_at_a_far_origin():
    # the new map's origin 80 m from the room: a 1 deg yaw difference moves T_PN's translation by 1.4 m
    T_PW, T_NW = _pose(_rz(-25.0), [0.4, 1.1, 0.0]), _pose(_rz(40.0), [80.0, -2.0, 0.3])
    prior, new = _sessions(T_PW, T_NW)
    res = align_sessions(prior, new, _match)
    assert res.localized and len(res.agreeing) == len(res.hypotheses) >= 15
    T_true = T_PW @ np.linalg.inv(T_NW)
    c = new[0].T_MS[:3, 3]                                     # checked where the views are
    err = res.T_PN[:3, :3] @ c + res.T_PN[:3, 3] - (T_true[:3, :3] @ c + T_true[:3, 3])
    assert np.linalg.norm(err) < 0.03


def test_yaws_either_side_of_180_degrees_agree():
    from runtime.graph.place_consensus import agreement

    hyps = [_hyp(1, 179.8, [1, 0, 0]), _hyp(2, -179.8, [1, 0, 0])]
    hyps[1].T_PN[:3, :3] = _rz(-179.8)[:3, :3]
    assert agreement(hyps, AlignConfig()).all()


def test_consensus_prefers_distinct_views_to_many_pairs_of_one_view():
    cfg = AlignConfig(min_views=3)
    one_view = [_hyp(9, 50.0, [3, 3, 0]) for _ in range(6)]
    spread = [_hyp(1, 10.0, [1, 0, 0]), _hyp(2, 10.2, [1, 0, 0]), _hyp(3, 9.9, [1, 0, 0])]
    group, reason = consensus(one_view + spread, cfg)
    assert sorted(group) == [6, 7, 8] and reason == "localized"


def test_the_mean_yaw_fit_when_the_agreeing_views_stand_close_together():
    T_PW, T_NW = _pose(_rz(-25.0), [0.4, 1.1, 0.0]), _pose(_rz(40.0), [1.5, -2.0, 0.3])
    prior, new = _sessions(T_PW, T_NW)
    res = align_sessions(prior, new, _match, AlignConfig(min_centre_spread_m=100.0))
    assert res.localized and res.fit == "mean yaw"
    T_true = T_PW @ np.linalg.inv(T_NW)
    c = new[0].T_MS[:3, 3]
    assert np.linalg.norm(res.T_PN[:3, :3] @ c + res.T_PN[:3, 3] - (T_true[:3, :3] @ c + T_true[:3, 3])) < 0.1


def test_a_failed_consensus_after_localisation_keeps_the_last_transform_and_says_so():
    T_PW, T_NW = _pose(_rz(-25.0), [0.4, 1.1, 0.0]), _pose(_rz(40.0), [1.5, -2.0, 0.3])
    prior, new = _sessions(T_PW, T_NW)
    loc = PriorMapLocalizer(prior, _match, AlignConfig())
    for b in new:
        loc.add_view(b)
    T = loc.T_PN(0)
    assert T is not None
    for b in new[:4]:                      # a drifted stretch: the same views, their poses 1 m off
        shifted = PlaceView(b.index + 100, _pose(np.eye(3), [1.0, 0.0, 0.0]) @ b.T_MS, b.features, b.view)
        loc.add_view(shifted)
    assert loc.consensus_lost >= 1 and np.array_equal(loc.T_PN(0), T)
    al = loc.alignment(0)
    assert al.localized and "last transform is kept" in al.reason and al.agreeing


def test_a_failing_match_is_counted_not_raised_by_the_live_prior_frame():
    from types import SimpleNamespace

    import cv2

    from runtime.graph.prior_frame import PriorFrame

    prior, new = _sessions(np.eye(4), np.eye(4))

    def broken(fa, fb):
        raise cv2.error("simulated OpenCV failure")

    pf = PriorFrame(PriorMapLocalizer(prior, broken, AlignConfig()), "prior")
    b = new[0]
    pf.on_submap(SimpleNamespace(index=0, T_MS=b.T_MS, view=(b.features, b.view), segment=0))
    assert pf.errors == 1 and "simulated OpenCV failure" in pf.error_messages[0]


def test_a_kept_transform_still_reports_its_group_after_its_hypotheses_were_dropped():
    T_PW, T_NW = _pose(_rz(-25.0), [0.4, 1.1, 0.0]), _pose(_rz(40.0), [1.5, -2.0, 0.3])
    prior, new = _sessions(T_PW, T_NW)
    loc = PriorMapLocalizer(prior, _match, AlignConfig(), max_hypotheses=12)
    for b in new:
        loc.add_view(b)
    group = len(loc.alignment(0).agreeing)
    for k in range(3):           # views each drifted its own way push the good hypotheses out of the list
        for j, b in enumerate(new):
            moved = _pose(np.eye(3), [1.0 + j + 6 * k, 0.0, 0.0]) @ b.T_MS
            loc.add_view(PlaceView(b.index + 100 * (k + 1), moved, b.features, b.view), search_near=False)
    al = loc.alignment(0)
    assert al.localized and loc.consensus_lost >= 1 and "last transform is kept" in al.reason
    # the kept group (the last consensus that held: good views only) is reported though no longer held
    assert len(al.hypotheses) > 12 and 3 <= len(al.agreeing) <= group
    assert all(al.hypotheses[i].new < 100 for i in al.agreeing) and al.as_dict()["agreeing_new_views"] >= 3


def test_binary_descriptors_rank_and_match_as_well():
    """ORB's packed bits (the matcher without the XFeat graph): ranked on +-1 bit vectors, matched by
    Hamming distance."""
    T_PW, T_NW = _pose(_rz(-25.0), [0.4, 1.1, 0.0]), _pose(_rz(40.0), [1.5, -2.0, 0.3])
    prior, new = _sessions(T_PW, T_NW)
    rng = np.random.default_rng(8)
    proj = rng.normal(size=(64, 256))                          # the same float -> bit map for every view

    def binary(views):
        out = []
        for v in views:
            bits = (v.features.desc.astype(np.float64) @ proj > 0)
            flips = rng.random(bits.shape) < 0.03
            desc = np.packbits(bits ^ flips, axis=1)
            out.append(PlaceView(v.index, v.T_MS, Features(v.features.kpts, v.features.scores, desc,
                                                            v.features.image_size, None), v.view))
        return out

    res = align_sessions(binary(prior), binary(new), _match)
    assert res.localized and res.hypotheses and res.hypotheses[0].n_inliers > 30
    T_true = T_PW @ np.linalg.inv(T_NW)
    assert np.linalg.norm(res.T_PN[:3, 3] - T_true[:3, 3]) < 0.05


def _look_alike_sessions(T_PW, T_NW, offset=(30.0, 0.0, 0.0)):
    """A prior map of the room seen from 9 ring positions (yaws 90-330) plus a look-alike room (the same
    walls, `offset` away) seen from the other three (yaws 0-60), and a new session of the room going
    round from yaw 8: its first views see walls that the prior map holds only in the look-alike."""
    pts, desc = _room(1)
    off = np.asarray(offset)

    def ring(yaws, shift=(0.0, 0.0, 0.0)):
        return [(1.5 * np.cos(np.radians(a)) + shift[0], 1.0 * np.sin(np.radians(a)) + shift[1],
                 1.4 + shift[2]) for a in yaws]

    true_yaws, twin_yaws = np.arange(90, 360, 30.0), np.array([0.0, 30.0, 60.0])
    prior = _session(pts, desc, T_PW, true_yaws, ring(true_yaws), seed=2)
    twin = _session(pts + off, desc, T_PW, twin_yaws, ring(twin_yaws, off), seed=4)
    for k, v in enumerate(twin):
        v.index = 100 + k
    new_yaws = np.arange(0, 360, 30.0) + 8.0
    return prior + twin, _session(pts, desc, T_NW, new_yaws, ring(new_yaws, (0.3, -0.2, 0.1)), seed=3)


def test_a_wrong_early_lock_on_a_look_alike_place_is_replaced_and_applied_at_once():
    from types import SimpleNamespace

    from runtime.graph.prior_frame import PriorFrame

    T_PW, T_NW = _pose(_rz(-25.0), [0.4, 1.1, 0.0]), _pose(_rz(40.0), [1.5, -2.0, 0.3])
    prior, new = _look_alike_sessions(T_PW, T_NW)
    T_true = T_PW @ np.linalg.inv(T_NW)
    pf = PriorFrame(PriorMapLocalizer(prior, _match, AlignConfig(words=64)), "prior")
    loc = pf.localizer
    T_MI = _pose(_rz(10.0), [1.0, 2.0, 0.5])
    errors, t_switch = [], None
    for k, b in enumerate(new):
        pf.on_submap(SimpleNamespace(index=b.index, T_MS=b.T_MS, view=(b.features, b.view), segment=0))
        t = 10**9 * (k + 1)
        pf.update(t)
        T = loc.T_PN(0)
        errors.append(np.inf if T is None else float(np.linalg.norm(T[:3, 3] - T_true[:3, 3])))
        if t_switch is None and loc.switches:
            t_switch = t
    wrong = [e for e in errors if 29.0 < e < 31.0]
    assert len(wrong) >= 2                        # first localised in the look-alike room, 30 m away
    assert errors[-1] < 0.03                      # then replaced by the room's own consensus
    assert loc.switches == {0: 1} and loc.switched_at(0) > 0 and loc.global_fallbacks >= 1
    # the live frame jumps to the replacing transform at once: no poses published between the two rooms
    T_at_switch = pf.pose(0, t_switch, T_MI)
    assert np.linalg.norm(T_at_switch[:3, 3] - (T_true @ T_MI)[:3, 3]) < 0.05
    rep = pf.report()
    assert rep["switches"] == 1 and rep["segments"]["0"]["switches"] == 1 and rep["global_fallbacks"] >= 1


def test_a_consistent_refinement_is_not_counted_as_a_switch():
    from runtime.graph.place_consensus import transforms_agree

    cfg = AlignConfig()
    T = _pose(_rz(30.0), [1.0, 2.0, 0.0])
    c = np.array([5.0, 0.0, 1.0])
    assert transforms_agree(T, _pose(_rz(32.9), [1.0, 2.0, 0.0]), np.zeros(3), cfg)
    assert not transforms_agree(T, _pose(_rz(33.1), [1.0, 2.0, 0.0]), np.zeros(3), cfg)   # yaw beyond 3 deg
    # 2 deg about the frame's origin moves a point 5 m away by 0.17 m (agrees), 10 m away by 0.35 m
    T2 = _pose(_rz(32.0), [1.0, 2.0, 0.0])
    assert transforms_agree(T, T2, c, cfg) and not transforms_agree(T, T2, 2 * c, cfg)
    prior, new = _sessions(T, _pose(_rz(40.0), [1.5, -2.0, 0.3]))
    loc = PriorMapLocalizer(prior, _match, AlignConfig(words=64))
    changed = [loc.add_view(b) for b in new]
    assert changed.count(True) >= 2 and loc.switches == {} and loc.switched_at(0) == 0


def test_a_replacement_is_told_from_a_refinement():
    from runtime.graph.place_consensus import replaces

    cfg = AlignConfig()
    at = np.array([30.0, 0.0, 1.0])       # the new group's cameras 30 m from the new map's origin

    def group(views, yaw, t):
        out = [_hyp(v, yaw, t) for v in views]
        for h in out:
            h.c_N = at.copy()
        return out

    old = group([0, 1, 2], 0.0, [0.0, 0.0, 0.0])
    T_old = old[0].T_PN
    # a refinement that moves 0.37 m at 30 m (0.7 deg of yaw) but keeps two of the old pairs: not a switch
    ref = old[:2] + group([3, 4], 0.7, [0.0, 0.0, 0.0])
    held = {id(h) for h in old + ref}
    assert not replaces(old, T_old, ref, _pose(_rz(0.7), [0, 0, 0]), held, cfg)
    # another place's group while the old pairs are still held: a switch
    other = group([5, 6, 7], 0.0, [20.0, 0.0, 0.0])
    T_other = other[0].T_PN
    assert replaces(old, T_old, other, T_other, held | {id(h) for h in other}, cfg)
    # 2 m away (inside the 4 m bar): a switch while the old pairs are held, not once they aged out
    near = group([14, 15, 16], 0.0, [2.0, 0.0, 0.0])
    assert replaces(old, T_old, near, near[0].T_PN, held | {id(h) for h in near}, cfg)
    assert not replaces(old, T_old, near, near[0].T_PN, {id(h) for h in near}, cfg)
    # the old pairs aged out: a 0.4 m drift is not a switch, a 20 m jump is
    drift = group([8, 9, 10], 0.0, [0.4, 0.0, 0.0])
    assert not replaces(old, T_old, drift, drift[0].T_PN, {id(h) for h in drift}, cfg)
    assert replaces(old, T_old, other, T_other, {id(h) for h in other}, cfg)
    # agreeing transforms are never a switch
    assert not replaces(old, T_old, group([11, 12, 13], 0.0, [0.1, 0.0, 0.0]), _pose(_rz(0.0), [0.1, 0, 0]),
                        held, cfg)


def test_a_switch_followed_by_a_refinement_before_the_tracking_thread_looks_still_applies_at_once():
    """The model worker may commit the replacing transform and a refinement of it before the tracking
    thread's next update: the jump must not be blended from the wrong place."""
    from types import SimpleNamespace

    from runtime.graph.prior_frame import PriorFrame

    T_PW, T_NW = _pose(_rz(-25.0), [0.4, 1.1, 0.0]), _pose(_rz(40.0), [1.5, -2.0, 0.3])
    prior, new = _look_alike_sessions(T_PW, T_NW)
    T_true = T_PW @ np.linalg.inv(T_NW)
    pf = PriorFrame(PriorMapLocalizer(prior, _match, AlignConfig(words=64)), "prior")
    T_MI = _pose(_rz(10.0), [1.0, 2.0, 0.5])
    switch_view = None
    for k, b in enumerate(new):
        pf.on_submap(SimpleNamespace(index=b.index, T_MS=b.T_MS, view=(b.features, b.view), segment=0))
        if pf.localizer.switches and switch_view is None:
            switch_view = k
        if switch_view is None or k > switch_view + 1:
            pf.update(10**9 * (k + 1))
        if switch_view is not None and k == switch_view + 1:
            assert pf.localizer.version > pf.localizer.switched_at(0)     # a refinement came after it
            pf.update(10**9 * (k + 1))
            T_PI = pf.pose(0, 10**9 * (k + 1), T_MI)
            assert np.linalg.norm(T_PI[:3, 3] - (T_true @ T_MI)[:3, 3]) < 0.05
    assert switch_view is not None and switch_view + 1 < len(new)
