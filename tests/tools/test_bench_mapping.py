"""`davio bench mapping`: reference visibility, the ScaRF-style baseline's placement, and a short run."""
from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from models.da3.preprocess import normalise_poses
from models.depth_model import DepthPrediction
from models.emulated_da3.analytic import BoxRoom
from runtime.events import Frame
from runtime.mapping.config import MappingConfig
from runtime.mapping.mapper import Mapper
from runtime.mapping.windows import MappingWindow
from tools.benchmarks.scarf_mapper import ScarfMapper, place_window, window_similarity
from tools.cli import main
from tools.evaluation.visibility import visible_points

K = np.array([[100.0, 0.0, 31.5], [0.0, 100.0, 23.5], [0.0, 0.0, 1.0]])


def _pose(x: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = x
    return T


def test_visibility_front_back_fov_occlusion_and_tolerance():
    # camera 0 at the origin looking along +z at a wall z = 5; its left half (u < 32) is hidden by a
    # nearer plane z = 1. Camera 1, 10 m to the right, sees the bare wall.
    d0 = np.full((48, 64), 5.0, np.float32)
    d0[:, :32] = 1.0
    d1 = np.full((48, 64), 5.0, np.float32)
    d1[0, 0] = np.inf                                     # no surface at that pixel
    pts = np.array([
        [1.0, 0.0, 5.0],        # on the wall, right half of view 0: visible
        [-1.0, 0.0, 5.0],       # on the wall behind the near plane: occluded
        [-0.2, 0.0, 1.0],       # on the near plane: visible
        [1.0, 0.0, -5.0],       # behind camera 0 (and camera 1): not visible
        [10.0, 0.0, 5.0],       # outside view 0, straight ahead of view 1: visible
        [1.0, 0.0, 5.09],       # 9 cm behind a 5 m depth: within 2 % -> visible
        [1.0, 0.0, 5.2],        # 20 cm behind: not visible
        [-0.205, 0.0, 1.025],   # 2.5 cm behind a 1 m depth: within the 3 cm floor -> visible
        [-0.208, 0.0, 1.04],    # 4 cm behind a 1 m depth: not visible
        [10.0 - 0.315 * 5, -0.235 * 5, 5.0],  # view 1's pixel (0, 0), no surface there; outside view 0
    ])
    vis = visible_points(pts, np.stack([_pose(0.0), _pose(10.0)]), np.stack([d0, d1]), K)
    assert vis.tolist() == [True, False, True, False, True, True, False, True, False, False]
    only0 = visible_points(pts, _pose(0.0)[None], d0[None], K)
    assert not only0[4]


class _ScaledCameraDA3:
    """A conditioned 'DA3' with exact depth whose returned cameras have their centres scaled by
    `cam_scale` about camera 0 (DAVIO's gate sees s_hat = 1: the depth itself is right)."""

    def __init__(self, truth: BoxRoom, K_rect: np.ndarray, width: int, height: int, cam_scale: float) -> None:
        self.truth, self.K_rect, self.w, self.h, self.cam_scale = truth, K_rect, width, height, cam_scale
        self.rng = np.random.default_rng(0)

    def predict(self, frames, K=None, T_CW=None) -> DepthPrediction:
        views = [self.truth.render_view(f.t_ns, self.K_rect, self.w, self.h) for f in frames]
        depth = np.stack([v.depth for v in views]).astype(np.float32)
        T_WC = np.linalg.inv(T_CW)
        c = T_WC[:, :3, 3].copy()
        T_WC[:, :3, 3] = c[0] + self.cam_scale * (c - c[0])
        conf = (1.0 + self.rng.random(depth.shape)).astype(np.float32)
        _, d_norm = normalise_poses(T_CW)
        return DepthPrediction(depth, conf, np.linalg.inv(T_WC), np.asarray(K).copy(), 1.0 / d_norm, 0.0)


def _depth_ratio(points_W: np.ndarray, room: BoxRoom, t_ns: int, K_rect: np.ndarray, w: int, h: int) -> float:
    """Median of z / true depth of the points seen from the view at t_ns (1 = on the surfaces)."""
    Kf = K_rect.copy()                      # a 2x finer truth view (pixel centres kept)
    Kf[:2] *= 2.0
    Kf[:2, 2] += 0.5
    view = room.render_view(int(t_ns), Kf, 2 * w, 2 * h)
    R, c = view.T_WC[:3, :3], view.T_WC[:3, 3]
    p = (points_W - c) @ R
    z = p[:, 2]
    u = np.round(Kf[0, 0] * p[:, 0] / z + Kf[0, 2]).astype(int)
    v = np.round(Kf[1, 1] * p[:, 1] / z + Kf[1, 2]).astype(int)
    ok = (z > 0) & (u >= 0) & (u < 2 * w) & (v >= 0) & (v < 2 * h)
    d = view.depth[v[ok], u[ok]]
    fin = np.isfinite(d)
    assert fin.sum() > 100
    return float(np.median(z[ok][fin] / d[fin]))


def test_scarf_similarity_scales_the_window_but_davio_placement_does_not():
    w, h = 96, 72
    K_rect = np.array([[70.0, 0.0, 47.5], [0.0, 70.0, 35.5], [0.0, 0.0, 1.0]])
    room = BoxRoom()
    stamps = (np.arange(5) * 0.25e9).astype(np.int64)
    frames = [Frame(int(t), np.zeros((h, w), np.uint8)) for t in stamps]
    T_OC = np.stack([room.T_WC(int(t)) for t in stamps])      # true poses as the "VIO" poses
    window = MappingWindow(0, frames, T_OC, 0)
    camera = SimpleNamespace(K=K_rect, width=w, height=h, is_pinhole_rectified=True)

    model = _ScaledCameraDA3(room, K_rect, w, h, cam_scale=1.2)
    pred = model.predict(frames, np.tile(K_rect, (5, 1, 1)), np.linalg.inv(T_OC))
    placed = place_window(pred.T_CW, pred.depth, T_OC)
    assert placed.sim.s == pytest.approx(1 / 1.2, rel=1e-9)
    np.testing.assert_allclose(placed.T_OC[:, :3, 3], T_OC[:, :3, 3], atol=1e-9)
    np.testing.assert_allclose(placed.depth, pred.depth / 1.2, rtol=1e-6)

    scarf = ScarfMapper(_ScaledCameraDA3(room, K_rect, w, h, cam_scale=1.2))
    scarf.process(window)
    davio = Mapper(_ScaledCameraDA3(room, K_rect, w, h, cam_scale=1.2), camera, MappingConfig(),
                   matcher=False)
    assert davio.process(window) is not None
    assert davio.stats.windows_accepted == 1
    # exact depth at the metric poses stays on the surfaces; ScaRF's similarity shrinks it by 1/1.2
    ratio = lambda pts: _depth_ratio(pts, room, stamps[2], K_rect, w, h)  # noqa: E731
    assert ratio(davio.fused_points()[0]) == pytest.approx(1.0, abs=0.01)
    assert ratio(scarf.points()[0]) == pytest.approx(1 / 1.2, abs=0.03)

    # a generic similarity between the model's world and the input one is recovered exactly
    S = np.eye(4)
    S[:3, :3] = BoxRoom().T_WC(0)[:3, :3]
    S[:3, 3] = [0.3, -1.0, 2.0]
    T_WC_model = S @ T_OC
    T_WC_model[:, :3, 3] = 0.7 * T_WC_model[:, :3, 3]
    sim = window_similarity(np.linalg.inv(T_WC_model), T_OC)
    assert sim.s == pytest.approx(1 / 0.7) and sim.rmse_y < 1e-9
    np.testing.assert_allclose(sim.R, S[:3, :3].T, atol=1e-12)

    control = ScarfMapper(_ScaledCameraDA3(room, K_rect, w, h, cam_scale=1.0))
    control.process(window)
    assert ratio(control.points()[0]) == pytest.approx(1.0, abs=0.01)


@pytest.mark.slow
def test_bench_mapping_short_run(capsys):
    assert main(["bench", "mapping", "--preset", "euroc", "--seconds", "6", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    seq = out["sequences"]["preset euroc (room)"]
    assert sorted(seq["rows"]) == list("abcdefghij")
    assert seq["windows"] >= 1 and seq["reference"]["reference_voxels"] > 1000
    for row in seq["rows"].values():
        assert row["windows_offered"] == seq["windows"]
    assert seq["rows"]["d"]["precision"] > 0.5
    assert set(seq["goals"]) == {"f10_a_minus_c", "mean_a_over_c", "f10_a_minus_b"}


def test_relative_truth_windows_keep_the_vio_centre_and_the_true_relative_poses():
    from types import SimpleNamespace

    from runtime.geometry import make_pose, so3_exp
    from runtime.mapping.windows import MappingWindow
    from tools.benchmarks.mapping_variants import relative_truth_windows

    rng = np.random.default_rng(5)
    truth = np.array([make_pose(so3_exp(rng.normal(0, 0.2, 3)), rng.normal(0, 1, 3)) for _ in range(5)])
    vio = np.array([T @ make_pose(so3_exp(rng.normal(0, 0.02, 3)), rng.normal(0, 0.05, 3)) for T in truth])
    frames = [None] * 5
    inputs = SimpleNamespace(windows=[MappingWindow(0, frames, vio, 0)],
                             windows_gt=[MappingWindow(0, frames, truth, 0)])
    (w,) = relative_truth_windows(inputs)
    np.testing.assert_allclose(w.T_OC[2], vio[2], atol=1e-12)
    for i in range(5):
        np.testing.assert_allclose(np.linalg.inv(w.T_OC[2]) @ w.T_OC[i], np.linalg.inv(truth[2]) @ truth[i],
                                   atol=1e-12)
    assert w.window_id == 0 and w.segment == 0


class _SlantedTruth:
    """z-depth 4 + 0.05 u (varies along u only, so a swapped u/v or a pixel off shows), with no surface
    left of u = 40 (most of the submap's points: they must not vote)."""

    def render_view(self, t_ns: int, K: np.ndarray, width: int, height: int) -> SimpleNamespace:
        d = np.repeat((4.0 + 0.05 * np.arange(width))[None], height, axis=0)
        d[:, :40] = np.inf
        return SimpleNamespace(depth=d)


def _submap_at(lam_true: float, lam: float, index: int = 0):
    """Two images of points on the slanted truth, each at exp(-lam_true) of its true depth, plus one point
    behind the camera."""
    from runtime.mapping.submap import Submap

    u, v = np.meshgrid(np.arange(0, 64, 2.0), np.arange(1, 47, 3.0))
    z = (4.0 + 0.05 * u.ravel()) * np.exp(-lam_true)
    x = np.c_[u.ravel(), v.ravel(), np.ones(u.size)] @ np.linalg.inv(K).T * z[:, None]
    x = np.vstack([x, [[-0.4, 0.0, -2.0]]])           # projects to u = 51.5 through z < 0
    n = len(x)
    T = np.repeat(np.eye(4)[None], 2, axis=0)
    return Submap(index, np.array([1, 2], np.int64), 0, np.eye(4), T, K, 1.0, np.ones(2),
                  np.vstack([x, x]).astype(np.float32), np.repeat([0, 1], n).astype(np.uint8),
                  np.ones(2 * n, np.float32), np.zeros(2 * n, np.uint8), np.eye(4), lam)


def test_lambda_against_the_true_log_depth_scale():
    """lambda* is the log ratio of the true to the submap's depth at the point's own pixel (points off any
    surface or behind the camera do not vote); the summary scores lambda against it and lambda = 0."""
    from tools.benchmarks.mapping_scale import lambda_errors, true_log_scale

    truth = _SlantedTruth()
    assert true_log_scale(_submap_at(0.1, lam=0.0), truth, 64, 48) == pytest.approx(0.1, abs=1e-5)
    subs = [_submap_at(0.1, lam=0.08, index=0), _submap_at(-0.05, lam=-0.05, index=1),
            _submap_at(0.0, lam=0.03, index=2)]
    out = lambda_errors(subs, truth, 64, 48)
    assert out["submaps"] == 3
    assert out["true_mean"] == pytest.approx((0.1 - 0.05 + 0.0) / 3, abs=1e-5)
    assert out["rms_error"] == pytest.approx(np.sqrt((0.02 ** 2 + 0.0 + 0.03 ** 2) / 3), abs=1e-5)
    assert out["rms_error_lambda_zero"] == pytest.approx(np.sqrt((0.1 ** 2 + 0.05 ** 2) / 3), abs=1e-5)
    assert out["correlation"] > 0.9


def test_paper_gauge_option_reaches_the_graph_config():
    import argparse

    from runtime.graph.config import GraphConfig
    from tools.benchmarks import mapping as bm

    p = argparse.ArgumentParser()
    bm.add_arguments(p)
    assert bm.graph_config(p.parse_args([])) is None
    cfg = bm.graph_config(p.parse_args(["--paper-gauge"]))
    assert isinstance(cfg, GraphConfig) and not cfg.gauge_lambda_free and GraphConfig().gauge_lambda_free


def test_preset_imu_option_reaches_the_preset_sources():
    import argparse

    from tools.benchmarks import mapping as bm

    p = argparse.ArgumentParser()
    bm.add_arguments(p)
    assert {s.imu_profile for s in bm.sources(p.parse_args([])) if s.kind == "preset"} == {"datasheet"}
    measured = bm.sources(p.parse_args(["--preset", "euroc", "--preset-imu", "euroc-measured"]))
    assert [s.imu_profile for s in measured] == ["euroc-measured"]
