"""numba ray caster of box scenes: per pixel the nearest hit, its z-depth, face, shading.

Rays are given in the camera frame with z = 1 (so the hit parameter is the z-depth). Box 0 is
the room shell (hit from inside, at the ray's exit); the other boxes are hit from outside.
Shading: albedo from the face's mip-mapped tile (trilinear), a point light with ambient term,
and for reflective faces a view-dependent specular term from a procedural environment.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

AMBIENT = 0.45
"""Ambient light level (radiance of an albedo-1 surface facing away from the light)."""
DIFFUSE = 0.75
"""Gain of the point light (Lambertian) term."""
SPECULAR = 0.55
"""Gain of the environment reflection on reflective faces."""


@njit(cache=True, nogil=True, inline="always")
def _sample(tex: np.ndarray, off: int, h: int, w: int, x: float, y: float) -> float:
    """Bilinear lookup with wrap-around; x, y in texels of this level (texel centres at +0.5)."""
    x -= 0.5
    y -= 0.5
    fx0 = math.floor(x)
    fy0 = math.floor(y)
    ax = x - fx0
    ay = y - fy0
    x0 = int(fx0)
    y0 = int(fy0)
    if x0 < 0 or x0 >= w:
        x0 %= w
    if y0 < 0 or y0 >= h:
        y0 %= h
    x1 = x0 + 1
    if x1 == w:
        x1 = 0
    y1 = y0 + 1
    if y1 == h:
        y1 = 0
    a = tex[off + y0 * w + x0]
    b = tex[off + y0 * w + x1]
    c = tex[off + y1 * w + x0]
    d = tex[off + y1 * w + x1]
    return (a * (1 - ax) + b * ax) * (1 - ay) + (c * (1 - ax) + d * ax) * ay


@njit(cache=True, nogil=True, inline="always")
def _trilinear(
    tex: np.ndarray,
    offset: np.ndarray,
    height: np.ndarray,
    width: np.ndarray,
    face: int,
    x: float,
    y: float,
    lod: float,
) -> float:
    n_levels = offset.shape[1]
    if lod <= 0.0:
        return _sample(tex, offset[face, 0], height[face, 0], width[face, 0], x, y)
    if lod >= n_levels - 1:
        s = 2.0 ** (n_levels - 1)
        lv = n_levels - 1
        return _sample(tex, offset[face, lv], height[face, lv], width[face, lv], x / s, y / s)
    l0 = int(lod)
    f = lod - l0
    s0 = 2.0**l0
    a = _sample(tex, offset[face, l0], height[face, l0], width[face, l0], x / s0, y / s0)
    b = _sample(
        tex, offset[face, l0 + 1], height[face, l0 + 1], width[face, l0 + 1], x / (2 * s0), y / (2 * s0)
    )
    return a * (1 - f) + b * f


@njit(cache=True, nogil=True, inline="always")
def _environment(rx: float, ry: float, rz: float) -> float:
    """Procedural surroundings seen in a mirror direction (unit vector), in [0, 1.2]."""
    v = 0.35 + 0.25 * math.sin(4.0 * rx + 1.3) * math.sin(3.0 * ry + 0.4) + 0.15 * math.sin(7.0 * rz)
    if rz > 0.75:  # bright ceiling lights
        v += 0.6
    return v


@njit(cache=True, nogil=True, inline="always")
def _slab(
    lo: np.ndarray, hi: np.ndarray, ox: float, oy: float, oz: float, i0: float, i1: float, i2: float
) -> tuple[float, float, int]:
    """Ray/box slab test: (entry t, exit t, axis of the entry face)."""
    tx1 = (lo[0] - ox) * i0
    tx2 = (hi[0] - ox) * i0
    ty1 = (lo[1] - oy) * i1
    ty2 = (hi[1] - oy) * i1
    tz1 = (lo[2] - oz) * i2
    tz2 = (hi[2] - oz) * i2
    tn = min(tx1, tx2)
    tf = max(tx1, tx2)
    ax = 0
    tyn = min(ty1, ty2)
    if tyn > tn:
        tn = tyn
        ax = 1
    tzn = min(tz1, tz2)
    if tzn > tn:
        tn = tzn
        ax = 2
    tf = min(tf, min(max(ty1, ty2), max(tz1, tz2)))
    return tn, tf, ax


@njit(parallel=True, cache=True, nogil=True, fastmath=True)
def cast(
    rays: np.ndarray,
    R_WC: np.ndarray,
    p_WC: np.ndarray,
    box_min: np.ndarray,
    box_max: np.ndarray,
    group_start: np.ndarray,
    group_min: np.ndarray,
    group_max: np.ndarray,
    node_min: np.ndarray,
    node_max: np.ndarray,
    node_left: np.ndarray,
    node_right: np.ndarray,
    node_axis: np.ndarray,
    node_first: np.ndarray,
    node_count: np.ndarray,
    node_order: np.ndarray,
    node_active: np.ndarray,
    group_active: np.ndarray,
    box_active: np.ndarray,
    tile_px: int,
    face_material: np.ndarray,
    albedo: np.ndarray,
    strength: np.ndarray,
    offset: np.ndarray,
    height: np.ndarray,
    width: np.ndarray,
    texel_m: float,
    pixel_angle: float,
    light_W: np.ndarray,
    out_radiance: np.ndarray,
    out_depth: np.ndarray,
    out_face: np.ndarray,
    out_strength: np.ndarray,
    want_strength: bool,
) -> None:
    """Cast one ray per pixel; writes radiance, z-depth (m, inf on a miss), face id, strength.

    Boxes 1.. are grouped: group g holds boxes group_start[g] .. group_start[g+1]-1 inside the
    bounding box (group_min[g], group_max[g]), tested first to skip the whole group. Groups are
    found through a BVH (drivers.sim.bvh.GroupBvh fields node_*), traversed near child first.
    The image is cut into square tiles of `tile_px` pixels (row-major); nodes, groups and boxes whose
    `*_active[tile]` flag is 0 (no ray of the tile can reach them: drivers.sim.tiles) are skipped.
    """
    H, W = rays.shape[0], rays.shape[1]
    tiles_x = (W + tile_px - 1) // tile_px
    ox, oy, oz = p_WC[0], p_WC[1], p_WC[2]
    for v in prange(H):
        stack = np.empty(64, np.int64)
        for u in range(W):
            tile = (v // tile_px) * tiles_x + u // tile_px
            cx, cy, cz = rays[v, u, 0], rays[v, u, 1], rays[v, u, 2]
            d0 = R_WC[0, 0] * cx + R_WC[0, 1] * cy + R_WC[0, 2] * cz
            d1 = R_WC[1, 0] * cx + R_WC[1, 1] * cy + R_WC[1, 2] * cz
            d2 = R_WC[2, 0] * cx + R_WC[2, 1] * cy + R_WC[2, 2] * cz
            i0 = 1.0 / d0 if d0 != 0.0 else 1e30
            i1 = 1.0 / d1 if d1 != 0.0 else 1e30
            i2 = 1.0 / d2 if d2 != 0.0 else 1e30
            # room shell: exit point
            best = np.inf
            best_face = -1
            t = (box_max[0, 0] - ox) * i0 if d0 > 0 else (box_min[0, 0] - ox) * i0
            if t < best:
                best = t
                best_face = 1 if d0 > 0 else 0
            t = (box_max[0, 1] - oy) * i1 if d1 > 0 else (box_min[0, 1] - oy) * i1
            if t < best:
                best = t
                best_face = 3 if d1 > 0 else 2
            t = (box_max[0, 2] - oz) * i2 if d2 > 0 else (box_min[0, 2] - oz) * i2
            if t < best:
                best = t
                best_face = 5 if d2 > 0 else 4
            if best <= 0.0:
                best = np.inf
                best_face = -1
            sp = 1
            stack[0] = 0
            while sp > 0:
                sp -= 1
                node = stack[sp]
                if node_active[tile, node] == 0:
                    continue
                tn, tf, ax = _slab(node_min[node], node_max[node], ox, oy, oz, i0, i1, i2)
                if not (tn <= tf and tf > 0.0 and tn < best):
                    continue
                if node_left[node] >= 0:
                    a = node_axis[node]
                    dpos = d0 > 0 if a == 0 else (d1 > 0 if a == 1 else d2 > 0)
                    if dpos:  # low child first: push high child below it
                        stack[sp] = node_right[node]
                        stack[sp + 1] = node_left[node]
                    else:
                        stack[sp] = node_left[node]
                        stack[sp + 1] = node_right[node]
                    sp += 2
                    continue
                for k in range(node_first[node], node_first[node] + node_count[node]):
                    g = node_order[k]
                    if group_active[tile, g] == 0:
                        continue
                    b0 = group_start[g]
                    b1 = group_start[g + 1]
                    if b1 - b0 > 1:
                        tn, tf, ax = _slab(group_min[g], group_max[g], ox, oy, oz, i0, i1, i2)
                        if not (tn <= tf and tf > 0.0 and tn < best):
                            continue
                    for b in range(b0, b1):
                        if box_active[tile, b] == 0:
                            continue
                        tn, tf, ax = _slab(box_min[b], box_max[b], ox, oy, oz, i0, i1, i2)
                        if tn <= tf and tn > 1e-9 and tn < best:
                            best = tn
                            if ax == 0:
                                side = 0 if d0 > 0 else 1
                            elif ax == 1:
                                side = 0 if d1 > 0 else 1
                            else:
                                side = 0 if d2 > 0 else 1
                            best_face = 6 * b + 2 * ax + side
            if best_face < 0:
                out_radiance[v, u] = 0.0
                out_depth[v, u] = np.inf
                out_face[v, u] = -1
                out_strength[v, u] = 0.0
                continue
            hx = ox + best * d0
            hy = oy + best * d1
            hz = oz + best * d2
            b = best_face // 6
            ax = (best_face % 6) // 2
            side = best_face % 2
            # outward normal of the visible face (room faces point inward)
            sgn = -1.0 if side == 0 else 1.0
            if b == 0:
                sgn = -sgn
            nx = sgn if ax == 0 else 0.0
            ny = sgn if ax == 1 else 0.0
            nz = sgn if ax == 2 else 0.0
            # texture coordinates on the face
            ua = (ax + 1) % 3
            va = (ax + 2) % 3
            hu = hx if ua == 0 else (hy if ua == 1 else hz)
            hv = hx if va == 0 else (hy if va == 1 else hz)
            tu = (hu - box_min[b, ua]) / texel_m
            tv = (hv - box_min[b, va]) / texel_m
            dn = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            cos_i = abs(d0 * nx + d1 * ny + d2 * nz) / dn
            footprint = best * math.sqrt(cx * cx + cy * cy + cz * cz) * pixel_angle / max(cos_i, 0.3)
            lod = math.log2(max(footprint / texel_m, 1e-6))
            alb = _trilinear(albedo, offset, height, width, best_face, tu, tv, lod)
            lx = light_W[0] - hx
            ly = light_W[1] - hy
            lz = light_W[2] - hz
            dist2 = lx * lx + ly * ly + lz * lz
            ndl = max(0.0, (lx * nx + ly * ny + lz * nz) / math.sqrt(dist2))
            rad = alb * (AMBIENT + DIFFUSE * ndl / (1.0 + 0.02 * dist2))
            if face_material[best_face] == 2:
                dd = (d0 * nx + d1 * ny + d2 * nz) / dn
                rx = d0 / dn - 2 * dd * nx
                ry = d1 / dn - 2 * dd * ny
                rz = d2 / dn - 2 * dd * nz
                rad += SPECULAR * _environment(rx, ry, rz)
            out_radiance[v, u] = rad
            out_depth[v, u] = best
            out_face[v, u] = best_face
            if want_strength:
                out_strength[v, u] = _trilinear(strength, offset, height, width, best_face, tu, tv, lod)
            else:
                out_strength[v, u] = 0.0
