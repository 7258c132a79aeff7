"""Front-end end to end: rendered images -> KLT tracker -> dynamic initializer, against the true motion."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from runtime.events import Frame, ImuSample
from runtime.msckf.init_common import gravity_angle_deg
from runtime.msckf.init_dynamic import DynamicInitConfig, DynamicInitializer
from runtime.msckf.tracker import KltTracker
from tests.runtime.test_msckf_init_dynamic import CAM, R_IC, T_IC, Motion

WALL_X = 4.0  # a textured wall x = 4 m facing the camera
FLOOR_Z = -1.5  # a textured floor 1.5 m below the start
TEXEL_M = 0.005  # texture resolution, m per texel
TEX_SIZE = 2400


def _texture(seed: int) -> np.ndarray:
    """Band-limited random texture (float32), multi-scale so corners exist at every distance."""
    rng = np.random.default_rng(seed)
    tex = np.zeros((TEX_SIZE, TEX_SIZE), np.float32)
    for cell, weight in ((64, 1.0), (16, 0.6), (6, 0.4)):
        coarse = rng.uniform(0, 1, (TEX_SIZE // cell, TEX_SIZE // cell)).astype(np.float32)
        tex += weight * cv2.resize(coarse, (TEX_SIZE, TEX_SIZE), interpolation=cv2.INTER_CUBIC)
    tex = cv2.GaussianBlur(tex, (0, 0), 2.0)
    tex = (tex - tex.min()) / (tex.max() - tex.min()) * 220 + 20
    return tex


WALL_TEX = _texture(11)
FLOOR_TEX = _texture(12)


def render(R_WC: np.ndarray, p_WC: np.ndarray) -> np.ndarray:
    """Grey image (uint8) of the wall and floor seen by the pinhole CAM at pose (R_WC, p_WC)."""
    u, v = np.meshgrid(np.arange(CAM.width, dtype=np.float64), np.arange(CAM.height, dtype=np.float64))
    rays_C = np.stack([(u - CAM.cx) / CAM.fx, (v - CAM.cy) / CAM.fy, np.ones_like(u)], axis=-1)
    d = rays_C @ R_WC.T
    with np.errstate(divide="ignore", invalid="ignore"):
        t_wall = np.where(d[..., 0] > 1e-6, (WALL_X - p_WC[0]) / d[..., 0], np.inf)
        t_floor = np.where(d[..., 2] < -1e-6, (FLOOR_Z - p_WC[2]) / d[..., 2], np.inf)
    hit_wall = t_wall <= t_floor
    t = np.where(hit_wall, t_wall, t_floor)
    P = p_WC + d * t[..., None]
    c = TEX_SIZE / 2
    # wall texture coordinates (y, z); floor texture coordinates (x, y)
    wall_map = (c + P[..., 1] / TEXEL_M, c - P[..., 2] / TEXEL_M)
    floor_map = (c + (P[..., 0] - 2.0) / TEXEL_M, c + P[..., 1] / TEXEL_M)
    img_w = cv2.remap(
        WALL_TEX,
        wall_map[0].astype(np.float32),
        wall_map[1].astype(np.float32),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REFLECT,
    )
    img_f = cv2.remap(
        FLOOR_TEX,
        floor_map[0].astype(np.float32),
        floor_map[1].astype(np.float32),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REFLECT,
    )
    img = np.where(hit_wall, img_w, img_f)
    img = np.where(np.isfinite(t), img, 0.0)
    return np.clip(img, 0, 255).astype(np.uint8)


@pytest.mark.slow
def test_tracker_feeds_dynamic_initializer() -> None:
    motion = Motion("general")
    tracker = KltTracker(CAM)
    init = DynamicInitializer(CAM, T_IC, DynamicInitConfig())
    t0, duration, imu_hz, cam_hz = 1.0, 2.5, 400.0, 20.0
    for i in range(int(duration * imu_hz) + 1):
        t = t0 + i / imu_hz
        _, _, _, w, f = motion.state(t)
        init.feed_imu(ImuSample(int(round(t * 1e9)), w, f))
    counts = []
    t = t0
    for j in range(int((duration - 0.01) * cam_hz) + 1):
        t = t0 + j / cam_hz
        R, p, _, _, _ = motion.state(t)
        img = render(R @ R_IC, p + R @ T_IC[:3, 3])
        res = tracker.track(Frame(int(round(t * 1e9)), img))
        counts.append(len(res))
        init.feed_tracks(res.t_ns, res.ids, res.uv)
    assert min(counts) >= 150
    out = init.try_initialize()
    assert out is not None, init.last_reason
    R, _, v, _, _ = motion.state(t)
    assert gravity_angle_deg(out.gravity_in_imu, R[2, :]) < 1.0
    assert np.linalg.norm(out.R_OI.T @ out.v_OI - R.T @ v) < 0.05
    assert out.info["reprojection_rms_px"] < 0.5
