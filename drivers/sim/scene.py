"""Procedural indoor scenes made of axis-aligned boxes, enclosing a given trajectory.

Box 0 is the room shell, seen from inside (walls, floor, ceiling); the others are seen from
outside: boxes on the floor, floor-to-ceiling pillars, shelves (sides, back and planks with
small boxes on them), and thin panels on the walls (posters or reflective windows). Nothing
comes closer than `clearance_m` to the trajectory. Every face has a material and a texture tile
(drivers.sim.texture). Scenes are reproducible from (positions, seed, style).

Face numbering: face f of box b has id 6 b + 2 axis + side (side 0 = the box's min side along
axis, 1 = max side); in-plane texture axes of a face with normal axis a are ((a+1)%3, (a+2)%3).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from drivers.sim.texture import (
    LOW_TEXTURE,
    MATERIAL_NAMES,
    REFLECTIVE,
    TEXTURED,
    TextureAtlas,
    build_atlas,
    make_tile,
)
from runtime.errors import ConfigError

STYLES = ("room", "hall")
"""Scene styles: a room (2-3 m margins, 3 m ceiling) or a hall (4-7 m margins, 6 m ceiling)."""


@dataclass
class Scene:
    """A box scene with per-face materials and textures.

    Attributes:
        box_min, box_max: (N, 3) float64 corners in the world frame, m (box 0 = room shell).
        kinds: N labels ("room", "box", "pillar", "shelf", "panel").
        face_material: (6N,) int32 material id per face (texture.TEXTURED / LOW_TEXTURE / REFLECTIVE).
        atlas: texture tiles of every face.
        group_start: (G+1,) int64: group g holds boxes group_start[g] .. group_start[g+1]-1 (box 0,
            the room, belongs to none); groups speed up ray casting (a shelf's parts form one).
        light_W: (3,) position of the point light, m.
        seed, style: how the scene was made.
    """

    box_min: np.ndarray
    box_max: np.ndarray
    kinds: list[str]
    face_material: np.ndarray
    atlas: TextureAtlas
    light_W: np.ndarray
    group_start: np.ndarray
    seed: int = 0
    style: str = "room"
    info: dict = field(default_factory=dict)

    @property
    def n_boxes(self) -> int:
        return int(self.box_min.shape[0])

    def group_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(G,3) min and max corners of each group's bounding box, m."""
        gs = self.group_start
        lo = np.array([self.box_min[gs[g] : gs[g + 1]].min(axis=0) for g in range(gs.size - 1)]).reshape(
            -1, 3
        )
        hi = np.array([self.box_max[gs[g] : gs[g + 1]].max(axis=0) for g in range(gs.size - 1)]).reshape(
            -1, 3
        )
        return lo, hi

    def surface_distance(self, points_W: np.ndarray) -> np.ndarray:
        """Distance (m) from each (N,3) world point to the nearest face of any box (room included)."""
        pts = np.asarray(points_W, dtype=np.float64).reshape(-1, 3)
        best = np.full(pts.shape[0], np.inf)
        for lo, hi in zip(self.box_min, self.box_max, strict=True):
            below, above = lo - pts, pts - hi
            outside = np.linalg.norm(np.maximum(np.maximum(below, above), 0.0), axis=1)
            inside = np.min(np.minimum(pts - lo, hi - pts), axis=1)
            best = np.minimum(best, np.where(inside > 0, inside, outside))
        return best

    def inside_any_object(self, points_W: np.ndarray, margin: float = 1e-6) -> np.ndarray:
        """True for points strictly inside a non-room box (deeper than `margin`)."""
        pts = np.asarray(points_W, dtype=np.float64).reshape(-1, 3)
        hit = np.zeros(pts.shape[0], bool)
        for lo, hi in zip(self.box_min[1:], self.box_max[1:], strict=True):
            hit |= np.all((pts > lo + margin) & (pts < hi - margin), axis=1)
        return hit

    def surface_points(self, spacing_m: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
        """Samples of all visible surfaces: (M,3) points, m, and (M,) albedo in [0, 1].

        Points hidden inside other boxes (e.g. the floor under a box) are left out.
        """
        pts_all, val_all = [], []
        tex = self.atlas.texel_m
        for b in range(self.n_boxes):
            lo, hi = self.box_min[b], self.box_max[b]
            for axis in range(3):
                ua, va = (axis + 1) % 3, (axis + 2) % 3
                us = np.arange(lo[ua] + spacing_m / 2, hi[ua], spacing_m)
                vs = np.arange(lo[va] + spacing_m / 2, hi[va], spacing_m)
                if us.size == 0 or vs.size == 0:
                    continue
                U, V = np.meshgrid(us, vs)
                for side in (0, 1):
                    p = np.zeros((U.size, 3))
                    p[:, ua], p[:, va] = U.ravel(), V.ravel()
                    p[:, axis] = lo[axis] if side == 0 else hi[axis]
                    face = 6 * b + 2 * axis + side
                    tile = self.atlas.tile(face)
                    iu = ((p[:, ua] - lo[ua]) / tex).astype(np.int64) % tile.shape[1]
                    iv = ((p[:, va] - lo[va]) / tex).astype(np.int64) % tile.shape[0]
                    keep = ~self.inside_any_object(p, margin=1e-3)
                    pts_all.append(p[keep])
                    val_all.append(tile[iv, iu][keep])
        return np.concatenate(pts_all), np.concatenate(val_all).astype(np.float32)

    def summary(self) -> dict:
        """Counts of objects by kind and of faces by material, and the room size."""
        kinds = {k: self.kinds.count(k) for k in sorted(set(self.kinds))}
        mats = {MATERIAL_NAMES[m]: int(np.sum(self.face_material == m)) for m in MATERIAL_NAMES}
        size = (self.box_max[0] - self.box_min[0]).round(2).tolist()
        return {
            "style": self.style,
            "seed": self.seed,
            "room_size_m": size,
            "objects": kinds,
            "face_materials": mats,
            "texel_m": self.atlas.texel_m,
        }


def _point_box_distance(pts: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.maximum(np.maximum(lo - pts, pts - hi), 0.0), axis=1)


def build_scene(
    positions_W: np.ndarray,
    seed: int = 0,
    style: str = "room",
    clearance_m: float = 0.6,
    texel_m: float = 0.01,
) -> Scene:
    """A seeded scene enclosing the (N,3) world positions (body and camera) with clearance.

    Args:
        positions_W: points the scene must leave free (trajectory samples), m.
        seed: random seed (same inputs + seed -> same scene).
        style: "room" or "hall".
        clearance_m: minimum distance from any object to any of positions_W, m.
        texel_m: level-0 texel size, m.
    """
    if style not in STYLES:
        raise ConfigError(f"unknown scene style {style!r}; choose one of {', '.join(STYLES)}")
    pos = np.asarray(positions_W, dtype=np.float64).reshape(-1, 3)
    if pos.shape[0] == 0 or not np.all(np.isfinite(pos)):
        raise ConfigError("a scene needs finite trajectory positions to enclose")
    rng = np.random.default_rng(seed)
    lo_t, hi_t = pos.min(axis=0), pos.max(axis=0)
    if style == "room":
        margin = rng.uniform(2.0, 3.0, size=2)
        height = 3.0
    else:
        margin = rng.uniform(4.0, 7.0, size=2)
        height = 6.0
    floor = lo_t[2] - 0.15
    room_lo = np.array([lo_t[0] - margin[0], lo_t[1] - margin[1], floor])
    room_hi = np.array([hi_t[0] + margin[0], hi_t[1] + margin[1], max(floor + height, hi_t[2] + 1.0)])
    boxes: list[tuple[np.ndarray, np.ndarray, str]] = [(room_lo, room_hi, "room")]
    group_start = [1]
    free = pos[:: max(1, pos.shape[0] // 4000)]

    def fits(lo: np.ndarray, hi: np.ndarray) -> bool:
        if np.any(lo < room_lo - 1e-9) or np.any(hi > room_hi + 1e-9):
            return False
        return bool(np.all(_point_box_distance(free, lo, hi) > clearance_m))

    def add(lo: np.ndarray, hi: np.ndarray, kind: str) -> bool:
        if fits(lo, hi):
            boxes.append((lo, hi, kind))
            group_start.append(len(boxes))
            return True
        return False

    area = float(np.prod(room_hi[:2] - room_lo[:2]))
    span = room_hi[:2] - room_lo[:2]

    def random_xy(size: np.ndarray) -> np.ndarray:
        return room_lo[:2] + rng.uniform(0, 1, 2) * np.maximum(span - size, 0.0)

    # floor boxes (some stacked)
    for _ in range(int(area / 6) + 4):
        size = np.array([*rng.uniform(0.3, 1.2, 2), rng.uniform(0.3, 1.2)])
        xy = random_xy(size[:2])
        lo = np.array([xy[0], xy[1], floor])
        if add(lo, lo + size, "box") and rng.uniform() < 0.3:
            top = size * np.array([0.7, 0.7, rng.uniform(0.4, 0.9)])
            lo2 = lo + np.array([0.1 * size[0], 0.1 * size[1], size[2]])
            add(lo2, lo2 + top, "box")
    # pillars: up to 10 tries each to find a free spot
    wanted, placed = int(area / 25) + 1, 0
    for _ in range(10 * wanted):
        w = rng.uniform(0.3, 0.6)
        xy = random_xy(np.array([w, w]))
        placed += add(np.array([xy[0], xy[1], floor]), np.array([xy[0] + w, xy[1] + w, room_hi[2]]), "pillar")
        if placed == wanted:
            break
    # shelves against a wall: sides, back, planks, small boxes on planks
    for _ in range(int(area / 20) + 1):
        wall = int(rng.integers(0, 4))
        width, depth, tall = rng.uniform(1.0, 2.2), rng.uniform(0.35, 0.5), rng.uniform(1.5, 2.2)
        along, normal = (0, 1) if wall < 2 else (1, 0)
        start = room_lo[along] + rng.uniform(0, 1) * max(span[along] - width, 0.0)
        lo = np.zeros(3)
        hi = np.zeros(3)
        lo[along], hi[along] = start, start + width
        if wall % 2 == 0:
            lo[normal], hi[normal] = room_lo[normal], room_lo[normal] + depth
        else:
            lo[normal], hi[normal] = room_hi[normal] - depth, room_hi[normal]
        lo[2], hi[2] = floor, floor + tall
        if not fits(lo, hi):
            continue
        th = 0.03
        parts = []
        side_a_hi = hi.copy()
        side_a_hi[along] = lo[along] + th
        parts.append((lo.copy(), side_a_hi))
        side_b_lo = lo.copy()
        side_b_lo[along] = hi[along] - th
        parts.append((side_b_lo, hi.copy()))
        back_lo, back_hi = lo.copy(), hi.copy()
        if wall % 2 == 0:
            back_hi[normal] = lo[normal] + th
        else:
            back_lo[normal] = hi[normal] - th
        parts.append((back_lo, back_hi))
        n_planks = int(rng.integers(3, 6))
        for k in range(n_planks):
            z = floor + (k + 0.15) * tall / n_planks
            plo, phi = lo.copy(), hi.copy()
            plo[2], phi[2] = z, z + th
            parts.append((plo, phi))
            x = lo[along] + th + 0.02
            while x < hi[along] - th - 0.15:
                bw = rng.uniform(0.08, 0.3)
                if x + bw > hi[along] - th:
                    break
                if rng.uniform() < 0.7:
                    blo, bhi = plo.copy(), phi.copy()
                    blo[along], bhi[along] = x, x + bw
                    blo[2] = z + th
                    bhi[2] = z + th + min(rng.uniform(0.1, 0.3), 0.8 * tall / n_planks)
                    inset = rng.uniform(0.02, 0.1)
                    if wall % 2 == 0:
                        blo[normal] += th + 0.01
                        bhi[normal] -= inset
                    else:
                        blo[normal] += inset
                        bhi[normal] -= th + 0.01
                    parts.append((blo, bhi))
                x += bw + rng.uniform(0.0, 0.1)
        for plo, phi in parts:
            boxes.append((plo, phi, "shelf"))
        group_start.append(len(boxes))
    # wall panels: posters or reflective windows, 2 cm thick
    for _ in range(int(area / 8) + 3):
        wall = int(rng.integers(0, 4))
        along, normal = (0, 1) if wall < 2 else (1, 0)
        width, tall = rng.uniform(0.5, 2.0), rng.uniform(0.4, 1.5)
        lo, hi = np.zeros(3), np.zeros(3)
        start = room_lo[along] + rng.uniform(0, 1) * max(span[along] - width, 0.0)
        lo[along], hi[along] = start, start + width
        if wall % 2 == 0:
            lo[normal], hi[normal] = room_lo[normal], room_lo[normal] + 0.02
        else:
            lo[normal], hi[normal] = room_hi[normal] - 0.02, room_hi[normal]
        lo[2] = floor + rng.uniform(0.8, 1.6)
        hi[2] = min(lo[2] + tall, room_hi[2] - 0.1)
        add(lo, hi, "panel")

    box_min = np.array([b[0] for b in boxes])
    box_max = np.array([b[1] for b in boxes])
    kinds = [b[2] for b in boxes]
    materials = np.zeros(6 * len(boxes), np.int32)
    for b, kind in enumerate(kinds):
        for axis in range(3):
            for side in range(2):
                f = 6 * b + 2 * axis + side
                if kind == "room":
                    # floor and walls textured; ceiling and one wall low-texture (painted)
                    materials[f] = LOW_TEXTURE if (axis == 2 and side == 1) else TEXTURED
                elif kind == "panel":
                    materials[f] = REFLECTIVE if b % 3 == 0 else TEXTURED
                elif kind == "pillar":
                    materials[f] = LOW_TEXTURE if b % 2 == 0 else TEXTURED
                else:
                    materials[f] = rng.choice([TEXTURED, LOW_TEXTURE, REFLECTIVE], p=[0.75, 0.17, 0.08])
    materials[int(rng.choice([0, 2, 3]))] = LOW_TEXTURE  # one painted wall, not the one ahead at the start
    tiles = []
    for f in range(materials.size):
        b, axis = f // 6, (f % 6) // 2
        ext = box_max[b] - box_min[b]
        tiles.append(make_tile(int(materials[f]), (ext[(axis + 2) % 3], ext[(axis + 1) % 3]), texel_m, rng))
    atlas = build_atlas(tiles, texel_m)
    light = np.array([(room_lo[0] + room_hi[0]) / 2, (room_lo[1] + room_hi[1]) / 2, room_hi[2] - 0.3])
    return Scene(
        box_min,
        box_max,
        kinds,
        materials,
        atlas,
        light,
        np.array(group_start, np.int64),
        seed=seed,
        style=style,
    )
