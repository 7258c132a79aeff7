"""The mapper end to end on exact synthetic depth: every retained point lies on the room's walls,
injected flying pixels are rejected, and evicted submaps leave the live grid."""
from __future__ import annotations

import dataclasses

import numpy as np
from mapping_synth import H_TEST, K_TEST, W_TEST, look_at, render_room_depth

from calib.camera import Pinhole
from models.da3.preprocess import normalise_poses
from models.depth_model import DepthPrediction
from runtime.events import Frame
from runtime.mapping.config import MappingConfig
from runtime.mapping.fusion import VoxelGrid
from runtime.mapping.mapper import Mapper
from runtime.mapping.windows import MappingWindow

ROOM = (-3.0, 4.0, -2.0, 4.0, 0.0, 3.0)


class _ExactModel:
    """Returns the true depth of the room for the input poses (as a conditioned DA3 that is exact),
    optionally with flying pixels in one image."""

    K_rect = K_TEST

    def __init__(self, fly_image: int | None = None) -> None:
        self.fly_image = fly_image
        self.flying = None

    def predict(self, frames, K=None, T_CW=None):
        T_WC = np.linalg.inv(T_CW)
        depth = np.stack([render_room_depth(T, room=ROOM) for T in T_WC]).astype(np.float32)
        if self.fly_image is not None:
            rng = np.random.default_rng(0)
            self.flying = rng.random((H_TEST, W_TEST)) < 0.05
            depth[self.fly_image][self.flying] *= 0.6
        _, d = normalise_poses(T_CW)
        conf = np.ones_like(depth)
        return DepthPrediction(depth, conf, T_CW, K, 1.0 / d, 0.0)


def _distance_to_room(p: np.ndarray) -> np.ndarray:
    lo, hi = np.array(ROOM[0::2]), np.array(ROOM[1::2])
    return np.minimum(np.abs(p - lo), np.abs(p - hi)).min(axis=1)


def _window(k: int, start: float = 0.0) -> MappingWindow:
    poses = np.stack([look_at(np.array([start + 0.15 * i, 0.0, 1.0]), np.array([start + 0.15 * i, 4.0, 1.2]))
                      for i in range(5)])
    frames = [Frame(int((k * 3 + i) * 5e8), np.full((H_TEST, W_TEST), 128, np.uint8)) for i in range(5)]
    return MappingWindow(k, frames, poses, 0)


def _mapper(model, **cfg) -> Mapper:
    cam = Pinhole(W_TEST, H_TEST, K_TEST[0, 0], K_TEST[1, 1], K_TEST[0, 2], K_TEST[1, 2])
    return Mapper(model, cam, MappingConfig(pixel_stride=2, conf_percentile=0.0, **cfg), matcher=False)


def test_retained_points_lie_on_the_surfaces_and_flying_pixels_go():
    model = _ExactModel(fly_image=1)
    mapper = _mapper(model)
    commit = mapper.process(_window(0))
    sm = commit.submap
    p = sm.points_M()
    assert sm.n_points > 0.8 * 5 * (H_TEST // 2) * (W_TEST // 2) * 0.9
    assert np.max(_distance_to_room(p)) < 1e-3        # exact depth, exact poses: on the walls
    st = mapper.stats
    assert st.rejected_multiview > 0.9 * model.flying[1::2, 1::2].sum()
    assert np.allclose(sm.T_OS, _window(0).T_OC[2]) and np.allclose(sm.T_SC[2], np.eye(4))


def test_points_are_float32_depths_on_the_sample_grid_so_the_archive_stores_them_as_rays():
    """Each retained point is the model's float32 depth at a grid pixel, on that pixel's ray of K: the map
    archive then stores depth and pixel (schema 3) and reads the same points back."""
    from tools.map_archive.point_rays import decode_rays, encode_rays

    model = _ExactModel()
    sm = _mapper(model).process(_window(0)).submap
    rays = encode_rays(sm.points_C, sm.K)
    assert rays is not None
    u, v = rays["pixel_u"].astype(int), rays["pixel_v"].astype(int)
    assert set(np.unique(u)) <= set(range(1, W_TEST, 2)) and set(np.unique(v)) <= set(range(1, H_TEST, 2))
    T_WC = _window(0).T_OC
    truth = np.stack([render_room_depth(T, room=ROOM) for T in T_WC]).astype(np.float32)
    np.testing.assert_allclose(rays["depth"], truth[sm.image, v, u], rtol=1e-5)
    np.testing.assert_array_equal(decode_rays(rays["depth"], u, v, sm.K), sm.points_C)


def test_a_surface_only_one_image_sees_is_kept_unverified_or_dropped_by_the_paper_rule():
    """Image 0 looks at the side wall that no other image of the window sees: its depths are unseen.
    The default keeps them (counted as unverified); the paper's strict rule drops them."""
    w = _window(0)
    poses = np.array(w.T_OC)
    poses[0] = look_at(np.array([0.0, 0.0, 1.0]), np.array([-4.0, 0.3, 1.2]))
    w = MappingWindow(0, w.frames, poses, 0)
    n_grid = (H_TEST // 2) * (W_TEST // 2)
    subs, stats = [], []
    for keep_unseen in (True, False):
        mapper = _mapper(_ExactModel(), multiview_keep_unseen=keep_unseen)
        subs.append(mapper.process(w).submap)
        stats.append(mapper.stats)
    kept, strict = subs
    from_0 = [int((s.image == 0).sum()) for s in subs]
    assert from_0[0] > 0.95 * n_grid and from_0[1] < 0.02 * n_grid
    assert stats[0].points_unverified >= from_0[0] and stats[1].points_unverified == 0
    assert stats[1].rejected_multiview - stats[0].rejected_multiview == stats[0].points_unverified
    assert np.max(_distance_to_room(kept.points_M())) < 1e-3     # exact depth: the kept ones are right


class _DisagreeingModel(_ExactModel):
    """Exact depth with independent per-pixel log-normal errors (sigma 0.8): another image agrees
    within 10 % with about one depth in five."""

    def predict(self, frames, K=None, T_CW=None):
        pred = super().predict(frames, K, T_CW)
        rng = np.random.default_rng(3)
        depth = pred.depth * np.exp(0.8 * rng.standard_normal(pred.depth.shape)).astype(np.float32)
        return DepthPrediction(depth, pred.conf, pred.T_CW, pred.K, pred.scale, pred.fit_rmse_m)


def test_a_window_whose_images_disagree_is_refused_as_a_whole():
    from runtime.mapping.conditioned import WindowFit

    mapper = _mapper(_DisagreeingModel())
    out = mapper.process(_window(0))
    st = mapper.stats
    assert isinstance(out, WindowFit) and not out.accepted and out.reason == "multiview"
    assert st.windows_rejected == {"multiview": 1} and st.windows_accepted == 0
    assert st.points_retained == 0 and st.points_unverified == 0 and not mapper.resident
    assert st.rejected_multiview > 0.5 * st.points_sampled          # most depths failed the test
    # switched off (1.0, the paper's behaviour): the same window becomes a submap of the survivors
    off = _mapper(_DisagreeingModel(), max_multiview_failed_fraction=1.0)
    sub = off.process(_window(0)).submap
    assert off.stats.windows_accepted == 1 and sub.n_points == off.stats.points_retained > 0
    # the exact model's window, whose flying pixels fail in one image only, stays far below the bound
    assert _mapper(_ExactModel(fly_image=1)).process(_window(0)).submap.n_points > 0


class _UnitsModel(_ExactModel):
    """The exact depth times `factor` (1000: millimetres; -1: negative), the poses right: a user's export
    whose depth is in other units."""

    def __init__(self, factor: float) -> None:
        super().__init__()
        self.factor = factor

    def predict(self, frames, K=None, T_CW=None):
        pred = super().predict(frames, K, T_CW)
        return dataclasses.replace(pred, depth=pred.depth * self.factor)


def test_a_window_whose_depths_are_mostly_out_of_range_is_refused_not_committed_empty():
    """Depth in mm (every depth beyond max_depth_m) or negative: the window was accepted and committed as an
    empty submap, and map.ply had 0 vertices with no warning."""
    from runtime.mapping.conditioned import WindowFit

    for factor in (1000.0, -1.0):
        mapper = _mapper(_UnitsModel(factor))
        out = mapper.process(_window(0))
        st = mapper.stats
        assert isinstance(out, WindowFit) and not out.accepted and out.reason == "invalid_depth"
        assert st.windows_rejected == {"invalid_depth": 1} and st.windows_accepted == 0
        assert not mapper.resident
        assert st.rejected_invalid_depth == st.points_sampled > 0
    assert _mapper(_UnitsModel(1.0)).process(_window(0)).submap.n_points > 0
    off = _mapper(_UnitsModel(1000.0), min_valid_depth_fraction=0.0)        # the check switched off
    assert off.process(_window(0)).submap.n_points == 0


def test_evicted_submaps_leave_the_live_grid():
    mapper = _mapper(_ExactModel(), max_resident_submaps=2)
    subs = [mapper.process(_window(k, start=0.45 * k)).submap for k in range(4)]
    assert mapper.stats.submaps_evicted == 2 and [s.index for s in mapper.resident] == [2, 3]
    fresh = VoxelGrid(mapper.cfg.voxel_m)
    for s in subs[2:]:
        fresh.integrate(s.points_M(), s.grey)
    live, fresh_pts = mapper.fused_points(), fresh.points()
    assert np.array_equal(mapper.grid.keys, fresh.keys)            # both sorted by voxel key
    assert np.array_equal(live[2], fresh_pts[2])
    assert np.allclose(live[0], fresh_pts[0], atol=1e-9)


def test_graph_moves_of_submaps_that_left_memory_are_reported_as_states():
    """The graph keeps more nodes than the fused submaps: when a solve moves a submap that already left
    memory, the commit reports its new state (a SubmapState, points in the archive only)."""
    from runtime.mapping.submap import SubmapState

    mapper = _mapper(_ExactModel(), max_resident_submaps=2)
    for k in range(5):
        mapper.process(_window(k, start=0.45 * k))
    assert [s.index for s in mapper.resident] == [3, 4] and 1 in mapper.backend.graph
    before = mapper.backend.state(1)[1]
    mapper.backend.add_revisit(1, 4, 0.2, None)          # a scale link that pulls lambda_1 down
    commit = mapper.process(_window(5, start=2.25))
    states = {c.index: c for c in commit.changed if isinstance(c, SubmapState)}
    resident = {3, 4}                                    # in memory when the commit's graph was solved
    assert 1 in states and not set(states) & resident
    assert all(c.index in resident for c in commit.changed if not isinstance(c, SubmapState))
    s1 = states[1]
    T_MS, lam = mapper.backend.state(1)
    assert s1.lam == lam != before and np.array_equal(s1.T_MS, T_MS)
    assert s1.version == commit.version and s1.n_points > 0 and s1.segment == 0


def test_centre_views_hold_pyramid_features_for_revisits():
    """The graph keeps each submap's centre view with features at RevisitConfig.view_scales (levels
    0, 1, 2 by default), or the single-scale features of the frame-scale step with (1.0,)."""
    from models.matcher import Matcher
    from runtime.graph.config import RevisitConfig

    rng = np.random.default_rng(0)
    texture = (rng.random((H_TEST // 4, W_TEST // 4)) * 255).astype(np.uint8)
    image = np.kron(texture, np.ones((4, 4), np.uint8))               # 4 px squares: corners everywhere
    cam = Pinhole(W_TEST, H_TEST, K_TEST[0, 0], K_TEST[1, 1], K_TEST[0, 2], K_TEST[1, 2])
    levels = {}
    for scales in ((1.0, 0.7, 0.5), (1.0,)):
        mapper = Mapper(_ExactModel(), cam, MappingConfig(pixel_stride=2, conf_percentile=0.0),
                        matcher=Matcher.default(top_k=256, threads=1),
                        revisits=RevisitConfig(view_scales=scales))
        w = _window(0)
        w = MappingWindow(0, [Frame(f.t_ns, image) for f in w.frames], w.T_OC, 0)
        mapper.process(w)
        f, view = mapper.backend.views.get(0)
        assert len(view.kpts) == len(f) > 0
        levels[scales] = None if f.level is None else sorted(set(f.level.tolist()))
    assert levels == {(1.0, 0.7, 0.5): [0, 1, 2], (1.0,): None}      # the committed XFeat graph
