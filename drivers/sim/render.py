"""Camera image formation for simulated scenes: distorted ray grid, ray casting, exposure, noise.

`Renderer` casts one ray per pixel of the rig's camera (lens distortion applied: the ray of pixel
(u, v) is the camera model's unprojection of (u, v), cached once) and turns scene radiance into
an 8-bit grey image: exposure gain, vignetting, optional motion blur (average of sub-exposure
renders), shot + read noise, quantisation. It also returns the per-pixel z-depth of what the
camera sees (m, inf where nothing is hit) and the face id.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from drivers.sim.bvh import build_bvh
from drivers.sim.expose import expose
from drivers.sim.raycast import cast
from drivers.sim.scene import Scene
from drivers.sim.threads import PARALLEL_KERNELS
from drivers.sim.tiles import TILE_PX, tile_bounds, tile_flags
from runtime.errors import ConfigError

if TYPE_CHECKING:
    from calib import CameraModel

DN_PER_RADIANCE = 260.0
"""Digital numbers per unit radiance at exposure gain 1 (mean image level ~110-120 DN, like EuRoC)."""

MAX_MOTION_BLUR_SAMPLES = 64
"""Most renders averaged per frame: each is a full render, so 64 already costs 64 times the time."""


@dataclass(frozen=True)
class ImageOptions:
    """Image-formation options (all off/neutral = exact noise-free rendering).

    Attributes:
        read_noise_dn: standard deviation of additive read noise, DN.
        shot_noise_dn2_per_dn: signal-dependent noise variance, DN^2 per DN of signal.
        exposure_variation: relative amplitude of slow exposure-gain changes (0.15 = +-15 %).
        exposure_period_s: typical period of those changes, s.
        motion_blur_samples: renders averaged over the exposure time (1 = no blur).
        exposure_time_s: shutter time over which motion blur integrates, s.
        vignetting: relative brightness loss at the image corners (0 = none).
    """

    read_noise_dn: float = 1.0
    shot_noise_dn2_per_dn: float = 0.02
    exposure_variation: float = 0.15
    exposure_period_s: float = 7.0
    motion_blur_samples: int = 1
    exposure_time_s: float = 0.004
    vignetting: float = 0.25

    @staticmethod
    def exact() -> ImageOptions:
        """No noise, constant exposure, no blur, no vignetting."""
        return ImageOptions(0.0, 0.0, 0.0, 7.0, 1, 0.0, 0.0)

    def __post_init__(self) -> None:
        if not 1 <= self.motion_blur_samples <= MAX_MOTION_BLUR_SAMPLES:
            raise ConfigError(f"motion_blur_samples (--motion-blur) must be from 1 to "
                              f"{MAX_MOTION_BLUR_SAMPLES} renders per frame, got {self.motion_blur_samples}")
        for name in (
            "read_noise_dn",
            "shot_noise_dn2_per_dn",
            "exposure_variation",
            "exposure_time_s",
            "vignetting",
        ):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"{name} must be >= 0, got {getattr(self, name)}")


@dataclass
class View:
    """One cast view: radiance (H,W) float32, z-depth (H,W) float32 m (inf = no hit), face (H,W) int32,
    strength (H,W) float32 texture strength in [0, 1] (zeros unless requested)."""

    radiance: np.ndarray
    depth: np.ndarray
    face: np.ndarray
    strength: np.ndarray


def ray_grid_from_unproject(unproject, width: int, height: int) -> np.ndarray:
    """(H, W, 3) float64 camera-frame rays with z = 1 for every pixel centre, via `unproject(uv (N,2))`."""
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    rays = np.asarray(unproject(np.stack([u.ravel(), v.ravel()], axis=1)), dtype=np.float64)
    if rays.shape != (width * height, 3) or not np.all(np.isfinite(rays)):
        raise ConfigError("the camera model did not unproject every pixel to a finite ray")
    rays = rays / rays[:, 2:3]
    return np.ascontiguousarray(rays.reshape(height, width, 3))


def pinhole_ray_grid(K: np.ndarray, width: int, height: int) -> np.ndarray:
    """(H, W, 3) rays with z = 1 of an undistorted pinhole camera with intrinsics K."""
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or not K[0, 0] > 0 or not K[1, 1] > 0:
        raise ConfigError(f"K must be a 3x3 intrinsic matrix with positive focal lengths, got {K!r}")
    Kinv = np.linalg.inv(K)
    return ray_grid_from_unproject(lambda uv: np.c_[uv, np.ones(len(uv))] @ Kinv.T, width, height)


class Caster:
    """Casts views of one scene through a fixed ray grid (camera-frame rays with z = 1)."""

    def __init__(self, scene: Scene, rays: np.ndarray, pixel_angle_rad: float) -> None:
        self.scene = scene
        self.rays = np.ascontiguousarray(rays, dtype=np.float64)
        self.height, self.width = rays.shape[:2]
        self.pixel_angle = float(pixel_angle_rad)
        self._gmin, self._gmax = scene.group_bounds()
        self._bvh = build_bvh(self._gmin, self._gmax)
        self._tiles = tile_bounds(self.rays, TILE_PX)

    def cast(self, R_WC: np.ndarray, p_WC: np.ndarray, want_strength: bool = False) -> View:
        """Cast the view of a camera at pose (R_WC, p_WC)."""
        H, W = self.height, self.width
        rad = np.empty((H, W), np.float32)
        depth = np.empty((H, W), np.float32)
        face = np.empty((H, W), np.int32)
        strength = np.empty((H, W), np.float32)
        s, a = self.scene, self.scene.atlas
        R_WC = np.ascontiguousarray(R_WC, dtype=np.float64)
        p_WC = np.ascontiguousarray(p_WC, dtype=np.float64)
        b = self._bvh
        with PARALLEL_KERNELS:
            box_active, group_active, node_active = tile_flags(
                s.box_min, s.box_max, s.group_start, R_WC, p_WC, self._tiles, b.left, b.right, b.first,
                b.count, b.order
            )
            cast(
                self.rays,
                R_WC,
                p_WC,
                s.box_min,
                s.box_max,
                s.group_start,
                self._gmin,
                self._gmax,
                b.node_min,
                b.node_max,
                b.left,
                b.right,
                b.axis,
                b.first,
                b.count,
                b.order,
                node_active,
                group_active,
                box_active,
                TILE_PX,
                s.face_material,
                a.albedo,
                a.strength,
                a.offset,
                a.height,
                a.width,
                a.texel_m,
                self.pixel_angle,
                s.light_W,
                rad,
                depth,
                face,
                strength,
                want_strength,
            )
        return View(rad, depth, face, strength)


class Renderer:
    """Renders the rig camera's distorted 8-bit images and true depth of a scene.

    Args:
        scene: the scene.
        camera: a calib.CameraModel (width, height, fx, unproject).
        options: image-formation options.
        seed: seed of the noise and exposure processes.
    """

    def __init__(
        self, scene: Scene, camera: CameraModel, options: ImageOptions | None = None, seed: int = 0
    ) -> None:
        self.camera = camera
        self.options = options or ImageOptions()
        rays = ray_grid_from_unproject(camera.unproject, int(camera.width), int(camera.height))
        self.caster = Caster(scene, rays, 1.0 / float(camera.fx))
        rng = np.random.default_rng(seed + 7919)
        self._exposure_phase = rng.uniform(0, 2 * np.pi, 3)
        self._seed = seed
        n_px = rays.shape[0] * rays.shape[1]
        # a bank of standard normals (a little over two frames), read from a random offset per frame
        self._normals = rng.standard_normal(2 * n_px + 7919).astype(np.float32)
        r2 = rays[..., 0] ** 2 + rays[..., 1] ** 2
        self._vignette = (1.0 - self.options.vignetting * np.clip(r2 / r2.max(), 0, 1)).astype(np.float32)

    def exposure_gain(self, t_s: float) -> float:
        """Relative exposure gain at time t_s (seconds since the recording start)."""
        o = self.options
        if o.exposure_variation == 0:
            return 1.0
        ph = self._exposure_phase
        w = 2 * np.pi / o.exposure_period_s
        x = (
            0.6 * np.sin(w * t_s + ph[0])
            + 0.3 * np.sin(2.3 * w * t_s + ph[1])
            + 0.1 * np.sin(5.1 * w * t_s + ph[2])
        )
        return float(1.0 + o.exposure_variation * x)

    def render(
        self, poses_WC: list[tuple[np.ndarray, np.ndarray]], t_s: float, frame_index: int
    ) -> tuple[np.ndarray, View]:
        """Image (H,W) uint8 and the View at the middle pose of `poses_WC` (sub-exposure poses).

        With one pose there is no motion blur; with several, their radiances are averaged.
        The noise is seeded by (seed, frame_index), so a frame renders identically every time: it is
        read from a fixed bank of normal samples at an offset drawn from (seed, frame_index).
        """
        if not poses_WC:
            raise ConfigError("render needs at least one camera pose")
        mid = self.caster.cast(*poses_WC[len(poses_WC) // 2])
        if len(poses_WC) > 1:
            acc = np.zeros_like(mid.radiance)
            for k, (R, p) in enumerate(poses_WC):
                acc += mid.radiance if k == len(poses_WC) // 2 else self.caster.cast(R, p).radiance
            radiance = acc / len(poses_WC)
        else:
            radiance = mid.radiance
        o = self.options
        offset = int(np.random.default_rng([self._seed, frame_index]).integers(0, self._normals.size))
        image = np.empty(radiance.shape, np.uint8)
        with PARALLEL_KERNELS:
            expose(
                radiance,
                DN_PER_RADIANCE * self.exposure_gain(t_s),
                self._vignette,
                o.read_noise_dn,
                o.shot_noise_dn2_per_dn,
                self._normals,
                offset,
                image,
            )
        return image, mid
