"""Procedural surface textures of simulated scenes, precomputed as mip-mapped tiles per face.

A tile holds the albedo (reflectance in [0, 1]) of one box face on a regular texel grid; faces
larger than the tile repeat it. Materials:
  TEXTURED   multi-octave value noise, sharp-edged rectangles, checker patches, blobs and
             text-like strokes (rich for FAST/KLT and learned features);
  LOW_TEXTURE nearly uniform paint with very faint large-scale variation;
  REFLECTIVE  dark, nearly uniform base; the renderer adds a view-dependent specular term.
A second tile holds the local texture strength in [0, 1] (local albedo contrast; 0 = textureless).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

TEXTURED, LOW_TEXTURE, REFLECTIVE = 0, 1, 2
"""Material ids stored per face."""

MATERIAL_NAMES = {TEXTURED: "textured", LOW_TEXTURE: "low-texture", REFLECTIVE: "reflective"}

MIP_LEVELS = 4
"""Number of mip levels per tile (each halves the resolution)."""

MAX_TILE = 1024
"""Largest tile side, texels."""

STRENGTH_CONTRAST = 0.08
"""Local albedo standard deviation (over ~3 cm) that maps to texture strength 1."""


@dataclass
class TextureAtlas:
    """All face tiles of a scene, flattened for the numba renderer.

    Attributes:
        albedo: flat float32 texels of every face and mip level.
        strength: flat float32 texture strength, same layout as albedo.
        offset: (F, MIP_LEVELS) int64 start of each tile in the flat arrays.
        height, width: (F, MIP_LEVELS) int64 tile sizes, texels.
        texel_m: size of a level-0 texel, m.
    """

    albedo: np.ndarray
    strength: np.ndarray
    offset: np.ndarray
    height: np.ndarray
    width: np.ndarray
    texel_m: float

    def tile(self, face: int, level: int = 0) -> np.ndarray:
        """The (h, w) albedo tile of one face at one mip level (a view)."""
        o, h, w = self.offset[face, level], self.height[face, level], self.width[face, level]
        return self.albedo[o : o + h * w].reshape(h, w)


def _value_noise(rng: np.random.Generator, h: int, w: int, wavelength: float) -> np.ndarray:
    """Smooth noise in [-1, 1] with features of about `wavelength` texels."""
    gh = max(2, int(np.ceil(h / wavelength)) + 2)
    gw = max(2, int(np.ceil(w / wavelength)) + 2)
    grid = rng.uniform(-1.0, 1.0, size=(gh, gw)).astype(np.float32)
    big = cv2.resize(grid, (int(gw * wavelength), int(gh * wavelength)), interpolation=cv2.INTER_CUBIC)
    return big[:h, :w]


def _multi_octave(rng: np.random.Generator, h: int, w: int, base: float, octaves: int) -> np.ndarray:
    out = np.zeros((h, w), np.float32)
    amp, total = 1.0, 0.0
    for k in range(octaves):
        out += amp * _value_noise(rng, h, w, max(2.0, base / 2**k))
        total += amp
        amp *= 0.6
    return out / total


def _textured(rng: np.random.Generator, h: int, w: int, texel_m: float) -> np.ndarray:
    img = 0.5 + 0.25 * _multi_octave(rng, h, w, base=0.6 / texel_m, octaves=6)
    area = h * w * texel_m**2
    # posters / panels: sharp-edged rectangles
    for _ in range(int(rng.poisson(1.5 * area)) + 1):
        rw, rh = rng.uniform(0.1, 0.8, 2) / texel_m
        x0, y0 = rng.uniform(0, w), rng.uniform(0, h)
        cv2.rectangle(img, (int(x0), int(y0)), (int(x0 + rw), int(y0 + rh)), float(rng.uniform(0.1, 0.9)), -1)
    # checker patches
    for _ in range(int(rng.poisson(0.4 * area))):
        sq = max(2, int(rng.uniform(0.02, 0.08) / texel_m))
        n = int(rng.integers(3, 8))
        x0, y0 = int(rng.uniform(0, w)), int(rng.uniform(0, h))
        a, b = sorted(rng.uniform(0.1, 0.9, 2))
        for i in range(n):
            for j in range(n):
                cv2.rectangle(
                    img,
                    (x0 + i * sq, y0 + j * sq),
                    (x0 + (i + 1) * sq - 1, y0 + (j + 1) * sq - 1),
                    float(a if (i + j) % 2 else b),
                    -1,
                )
    # blobs
    for _ in range(int(rng.poisson(3.0 * area))):
        r = max(1, int(rng.uniform(0.01, 0.12) / texel_m))
        cv2.circle(
            img,
            (int(rng.uniform(0, w)), int(rng.uniform(0, h))),
            r,
            float(rng.uniform(0.05, 0.95)),
            -1,
            lineType=cv2.LINE_AA,
        )
    # text-like strokes: rows of short random segments
    for _ in range(int(rng.poisson(1.0 * area))):
        x0, y0 = rng.uniform(0, w), rng.uniform(0, h)
        size = max(3.0, rng.uniform(0.015, 0.04) / texel_m)
        ink = float(rng.uniform(0.0, 0.2))
        for line in range(int(rng.integers(2, 6))):
            x = x0
            for _c in range(int(rng.integers(5, 20))):
                for _s in range(2):
                    p = (int(x + rng.uniform(0, size)), int(y0 + line * 1.8 * size + rng.uniform(0, size)))
                    q = (int(x + rng.uniform(0, size)), int(y0 + line * 1.8 * size + rng.uniform(0, size)))
                    cv2.line(img, p, q, ink, 1, lineType=cv2.LINE_AA)
                x += size * rng.uniform(1.0, 1.6)
    img = cv2.GaussianBlur(img, (0, 0), 0.7)
    return np.clip(img, 0.02, 0.98)


def _low_texture(rng: np.random.Generator, h: int, w: int, texel_m: float) -> np.ndarray:
    base = float(rng.uniform(0.55, 0.85))
    return np.clip(base + 0.015 * _value_noise(rng, h, w, 1.5 / texel_m), 0.0, 1.0).astype(np.float32)


def _reflective(rng: np.random.Generator, h: int, w: int, texel_m: float) -> np.ndarray:
    base = float(rng.uniform(0.08, 0.2))
    return np.clip(base + 0.01 * _value_noise(rng, h, w, 1.0 / texel_m), 0.0, 1.0).astype(np.float32)


def make_tile(
    material: int, size_m: tuple[float, float], texel_m: float, rng: np.random.Generator
) -> np.ndarray:
    """Level-0 albedo tile (h, w) float32 for a face of size_m = (extent along v, extent along u), m."""
    step = 2 ** (MIP_LEVELS - 1)  # sides are multiples of this so every mip level halves exactly
    h = int(min(MAX_TILE, step * max(1, np.ceil(size_m[0] / texel_m / step))))
    w = int(min(MAX_TILE, step * max(1, np.ceil(size_m[1] / texel_m / step))))
    maker = {TEXTURED: _textured, LOW_TEXTURE: _low_texture, REFLECTIVE: _reflective}[material]
    return maker(rng, h, w, texel_m).astype(np.float32)


def strength_of(tile: np.ndarray) -> np.ndarray:
    """Local texture strength in [0, 1]: albedo standard deviation over ~3 texels / STRENGTH_CONTRAST."""
    t = tile.astype(np.float64)
    mean = cv2.GaussianBlur(t, (0, 0), 3.0)
    sq = cv2.GaussianBlur(t * t, (0, 0), 3.0)
    std = np.sqrt(np.maximum(sq - mean * mean, 0.0))
    strength = np.clip(std / STRENGTH_CONTRAST, 0.0, 1.0)
    return np.where(strength < 1e-3, 0.0, strength).astype(np.float32)  # rounding residue of flat tiles


def build_atlas(tiles: list[np.ndarray], texel_m: float) -> TextureAtlas:
    """Mip-map every level-0 tile and pack all of them (and their strength) into one atlas."""
    f = len(tiles)
    offset = np.zeros((f, MIP_LEVELS), np.int64)
    height = np.zeros((f, MIP_LEVELS), np.int64)
    width = np.zeros((f, MIP_LEVELS), np.int64)
    chunks_a, chunks_s = [], []
    pos = 0
    for i, tile in enumerate(tiles):
        level = tile
        strength = strength_of(tile)
        for lv in range(MIP_LEVELS):
            if lv > 0:
                nh, nw = max(1, level.shape[0] // 2), max(1, level.shape[1] // 2)
                level = cv2.resize(level, (nw, nh), interpolation=cv2.INTER_AREA)
                strength = cv2.resize(strength, (nw, nh), interpolation=cv2.INTER_AREA)
            offset[i, lv] = pos
            height[i, lv], width[i, lv] = level.shape
            chunks_a.append(level.ravel())
            chunks_s.append(strength.ravel())
            pos += level.size
    return TextureAtlas(
        np.concatenate(chunks_a).astype(np.float32),
        np.concatenate(chunks_s).astype(np.float32),
        offset,
        height,
        width,
        float(texel_m),
    )
