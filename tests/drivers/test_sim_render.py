"""Renderer: depth lies on the scene, lens distortion is applied, features move as the truth predicts."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from drivers.sim.imu_synth import ImuErrorModel
from drivers.sim.recording import SimConfig, SimRecording
from drivers.sim.render import ImageOptions
from drivers.sim.rig import euroc_default_rig
from drivers.sim.texture import REFLECTIVE
from runtime.errors import ConfigError


@pytest.fixture(scope="module")
def rec() -> SimRecording:
    rig = euroc_default_rig()
    rig = rig.replace(camera=rig.camera.scaled(0.5, 0.5))  # 376 x 240, same lens
    cfg = SimConfig(
        preset="slow", seconds=3.0, seed=11, image=ImageOptions.exact(), imu_errors=ImuErrorModel.noise_free()
    )
    return SimRecording.from_preset(cfg, rig=rig)


def _pose_WC(rec: SimRecording, k: int) -> np.ndarray:
    return rec.gt_source.camera_pose(int(rec.frame_stamps_ns[k]))


def _project_cv(rec: SimRecording, p_C: np.ndarray) -> np.ndarray:
    cam = rec.rig.camera
    uv, _ = cv2.projectPoints(
        p_C.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), cam.K, np.asarray(cam.distortion)
    )
    return uv.reshape(-1, 2)


def test_backprojected_depth_lies_on_scene_surfaces(rec: SimRecording) -> None:
    for k in (0, 20, 45):
        _, view = rec.render(k)
        assert np.isfinite(view.depth).all()  # inside a closed room every ray hits
        cam = rec.rig.camera
        u, v = np.meshgrid(np.arange(cam.width), np.arange(cam.height))
        uv = np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float64)
        p_C = cam.unproject(uv) * view.depth.reshape(-1, 1)
        T = _pose_WC(rec, k)
        p_W = p_C @ T[:3, :3].T + T[:3, 3]
        dist = rec.scene.surface_distance(p_W)
        assert np.percentile(dist, 100) < 1e-4 * max(1.0, float(view.depth.max()))
        # lens distortion applied: OpenCV's radtan projection of each surface point returns its pixel
        pick = np.random.default_rng(k).choice(uv.shape[0], 3000, replace=False)
        np.testing.assert_allclose(_project_cv(rec, p_C[pick]), uv[pick], atol=2e-3)


def test_tracked_features_move_as_the_true_projection_predicts(rec: SimRecording) -> None:
    errors = []
    for k in (22, 30, 40):
        f0, v0 = rec.render(k)
        f1, _ = rec.render(k + 1)
        corners = cv2.goodFeaturesToTrack(
            f0.image, maxCorners=300, qualityLevel=0.01, minDistance=7, blockSize=7
        )
        pts = corners.reshape(-1, 2)
        iu, iv = np.rint(pts[:, 0]).astype(int), np.rint(pts[:, 1]).astype(int)
        # keep corners away from depth discontinuities (same face in the 7x7 neighbourhood)
        face = np.pad(v0.face, 3, mode="edge")
        same = np.ones(pts.shape[0], bool)
        for du in range(-3, 4):
            for dv in range(-3, 4):
                same &= face[iv + 3 + dv, iu + 3 + du] == v0.face[iv, iu]
        pts, iu, iv = pts[same], iu[same], iv[same]
        tracked, status, _ = cv2.calcOpticalFlowPyrLK(
            f0.image, f1.image, pts.astype(np.float32).reshape(-1, 1, 2), None, winSize=(21, 21), maxLevel=3
        )
        ok = status.ravel() == 1
        ray = rec.rig.camera.unproject(np.stack([iu, iv], axis=1).astype(np.float64))
        p_C0 = ray * v0.depth[iv, iu][:, None].astype(np.float64)
        T01 = np.linalg.inv(_pose_WC(rec, k + 1)) @ _pose_WC(rec, k)
        p_C1 = p_C0 @ T01[:3, :3].T + T01[:3, 3]
        predicted = _project_cv(rec, p_C1) + (pts - np.stack([iu, iv], axis=1))  # corner offset within pixel
        err = np.linalg.norm(tracked.reshape(-1, 2)[ok] - predicted[ok], axis=1)
        motion = np.linalg.norm(predicted[ok] - pts[ok], axis=1)
        assert np.median(motion) > 0.3  # the camera does move between these frames
        errors.append(err)
    err = np.concatenate(errors)
    assert err.size > 150
    assert np.median(err) < 0.5


def test_groundtruth_view_of_an_undistorted_pinhole(rec: SimRecording) -> None:
    K = np.array([[150.0, 0.0, 99.5], [0.0, 150.0, 74.5], [0.0, 0.0, 1.0]])
    t = int(rec.frame_stamps_ns[30])
    gv = rec.gt_source.render_view(t, K, 200, 150)
    assert gv.depth.shape == gv.texture.shape == gv.reflective.shape == gv.surface_id.shape == (150, 200)
    assert gv.depth.dtype == np.float32 and gv.surface_id.dtype == np.int32 and gv.reflective.dtype == bool
    assert not gv.dynamic.any()
    assert 0.0 <= gv.texture.min() and gv.texture.max() <= 1.0 and gv.texture.std() > 0.05
    np.testing.assert_allclose(gv.T_WC, _pose_WC(rec, 30), atol=1e-12)
    u, v = np.meshgrid(np.arange(200), np.arange(150))
    p_C = np.stack([(u - 99.5) / 150.0, (v - 74.5) / 150.0, np.ones_like(u, dtype=float)], -1).reshape(-1, 3)
    p_C *= gv.depth.reshape(-1, 1)
    p_W = p_C @ gv.T_WC[:3, :3].T + gv.T_WC[:3, 3]
    assert rec.scene.surface_distance(p_W).max() < 1e-4 * max(1.0, float(gv.depth.max()))
    np.testing.assert_array_equal(gv.reflective, rec.scene.face_material[gv.surface_id] == REFLECTIVE)


def test_images_are_reproducible_and_noise_has_the_configured_level(rec: SimRecording) -> None:
    noisy_cfg = replace(
        rec.config,
        image=ImageOptions(
            read_noise_dn=2.0, shot_noise_dn2_per_dn=0.0, exposure_variation=0.0, vignetting=0.0
        ),
    )
    noisy = SimRecording(
        rec.rig, rec.scene, rec.motion, rec.imu, rec.frame_stamps_ns, rec.groundtruth(), noisy_cfg, rec.info
    )
    a, _ = noisy.render(5)
    b, _ = noisy.render(5)
    clean, _ = rec.render(5)
    np.testing.assert_array_equal(a.image, b.image)
    diff = a.image.astype(float) - clean.image.astype(float)
    mid = (clean.image > 10) & (clean.image < 245)
    assert abs(np.std(diff[mid]) - np.sqrt(2.0**2 + 1 / 12)) < 0.15


def test_motion_blur_smooths_a_moving_frame(rec: SimRecording) -> None:
    blur_cfg = replace(
        rec.config, image=replace(ImageOptions.exact(), motion_blur_samples=5, exposure_time_s=0.04)
    )
    blurred = SimRecording(
        rec.rig, rec.scene, rec.motion, rec.imu, rec.frame_stamps_ns, rec.groundtruth(), blur_cfg, rec.info
    )
    sharp, _ = rec.render(40)
    soft, _ = blurred.render(40)
    energy = lambda img: float(np.mean(np.abs(cv2.Laplacian(img.astype(np.float32), cv2.CV_32F))))  # noqa: E731
    assert energy(soft.image) < 0.9 * energy(sharp.image)


def _tiles_hit(rays_W: np.ndarray, p_WC: np.ndarray, lo: np.ndarray, hi: np.ndarray, tile: int) -> np.ndarray:
    """(tiles,) bool, brute force: does a ray of the tile (H,W,3 world directions from p_WC) hit the box?"""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - p_WC) / rays_W, (hi - p_WC) / rays_W
    tn, tf = np.nanmax(np.minimum(t1, t2), axis=2), np.nanmin(np.maximum(t1, t2), axis=2)
    hit = (tn <= tf) & (tf > 0.0)
    H, W = hit.shape
    pad = np.zeros((-(-H // tile) * tile, -(-W // tile) * tile), bool)
    pad[:H, :W] = hit
    return pad.reshape(pad.shape[0] // tile, tile, pad.shape[1] // tile, tile).any(axis=(1, 3)).ravel()


def test_tile_flags_keep_every_box_a_ray_of_the_tile_hits() -> None:
    from scipy.spatial.transform import Rotation

    from drivers.sim.bvh import build_bvh
    from drivers.sim.render import pinhole_ray_grid
    from drivers.sim.threads import PARALLEL_KERNELS
    from drivers.sim.tiles import TILE_PX, tile_bounds, tile_flags

    rng = np.random.default_rng(5)
    rays = pinhole_ray_grid(np.array([[110.0, 0, 74], [0, 110, 58], [0, 0, 1]]), 150, 118)  # partial tiles
    R_WC = Rotation.from_rotvec([0.1, -0.2, 0.05]).as_matrix()
    p_WC = np.array([0.7, -0.4, 1.3])
    centre = p_WC + rng.uniform([-3, -2, -1], [3, 2, 8], (300, 3)) @ R_WC.T   # some behind the camera
    half = rng.uniform(0.02, 0.3, (300, 3))
    centre[:3] = p_WC + np.array([[0.0, 0, 0], [0.1, 0, 0.05], [0, 0, -1.0]]) @ R_WC.T
    # boxes 1-3: one holds the camera, one straddles z = 0, one lies wholly behind it
    half[:3] = [[0.5, 0.5, 0.5], [0.2, 0.2, 0.3], [0.4, 0.4, 0.4]]
    box_min = np.vstack([[-20.0, -20, -20], centre - half])       # box 0: the room shell
    box_max = np.vstack([[20.0, 20, 20], centre + half])
    group_start = np.r_[1, 1 + np.cumsum(rng.integers(1, 6, 120))]
    group_start = np.r_[group_start[group_start < 301], 301]
    spans = list(zip(group_start[:-1], group_start[1:], strict=True))
    bvh = build_bvh(np.array([box_min[a:b].min(axis=0) for a, b in spans]),
                    np.array([box_max[a:b].max(axis=0) for a, b in spans]))
    with PARALLEL_KERNELS:
        box_on, group_on, node_on = tile_flags(box_min, box_max, group_start, R_WC, p_WC, tile_bounds(rays),
                                               bvh.left, bvh.right, bvh.first, bvh.count, bvh.order)
    assert box_on.shape == (10 * 8, 301) and np.all(box_on[:, 0] == 1)
    assert np.all(box_on[:, 1] == 1) and np.all(box_on[:, 3] == 0)   # around the camera; wholly behind it
    rays_W = rays @ R_WC.T
    extra = []
    for b in range(1, 301):
        hit = _tiles_hit(rays_W, p_WC, box_min[b], box_max[b], TILE_PX)
        assert not np.any(hit & (box_on[:, b] == 0)), b       # never culled where a ray of the tile hits it
        extra.append(np.sum(box_on[:, b] & ~hit) / max(1, np.sum(box_on[:, b])))
    assert 0.0 < box_on[:, 1:].mean() < 0.2 and np.mean(extra) < 0.3   # and culled in most other tiles
    for g in range(group_on.shape[1]):
        assert np.array_equal(group_on[:, g], box_on[:, group_start[g]:group_start[g + 1]].any(axis=1))
    assert np.array_equal(node_on[:, 0], group_on.any(axis=1))
    with pytest.raises(ConfigError, match="z = 1"):
        tile_bounds(rays / np.linalg.norm(rays, axis=2, keepdims=True))


def test_tile_culling_changes_nothing_in_the_image(rec: SimRecording, monkeypatch) -> None:
    import drivers.sim.render as render_module

    caster = rec.renderer.caster
    poses = [_pose_WC(rec, k) for k in (3, 25, 50)]
    culled = [caster.cast(T[:3, :3], T[:3, 3], want_strength=True) for T in poses]
    real_flags = render_module.tile_flags

    def everything_active(*args):
        return tuple(np.ones_like(f) for f in real_flags(*args))

    monkeypatch.setattr(render_module, "tile_flags", everything_active)
    for T, a in zip(poses, culled, strict=True):
        b = caster.cast(T[:3, :3], T[:3, 3], want_strength=True)
        for name in ("face", "depth", "radiance", "strength"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
