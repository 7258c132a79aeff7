"""`davio bench map-export`: the end of a long run, fusing its map archive into map.ply, by archive size.

A run ends by fusing every archived submap at its latest graph state into voxels (`MapOutput.finish` ->
`tools.map_archive.export_map`). The bench writes an archive of synthetic submaps as a robot mapping a
long corridor would (a submap every 1.5 s at 0.25 m/s; five images 0.5 s apart; depths on a 4-pixel grid
of a 752 x 480 camera, 2 % depth noise, so that each submap adds new wall, floor and ceiling), and at each
size in --submaps times `fuse_archive` (the fusion step of the export, files read and placed) with
today's `VoxelGrid`, and, up to --anchor-max submaps, with the grid as it was before (`former_grid`: every
submap's sums joined at once by re-sorting the whole grid): the anchor of the same run. The two
must give the same voxels (the bench exits 1 otherwise). Peak traced memory of each fusion
(tracemalloc) is reported beside it. The points are synthetic: the figures are costs, not map quality.
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

from runtime.json_out import strict_dumps
from tools.cli_types import count, number_in

NAME = "map-export"
HELP = "the end of a long run: seconds and memory to fuse its map archive, by archive size"
DESCRIPTION = __doc__
SUBMAP_PERIOD_S = 1.5
SPEED_M_S = 0.25
WIDTH, HEIGHT, STRIDE = 752, 480, 4
K = np.array([[460.0, 0, 376.0], [0, 460.0, 240.0], [0, 0, 1]])
CORRIDOR_Y, CORRIDOR_Z = 1.2, (0.0, 2.6)
"""Corridor half-width and floor / ceiling heights, metres (the camera at 1.3 m, looking along +x)."""
R_WC = np.array([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]])
"""Camera axes in the world: z (optical axis) along +x, x to the right (-y), y down (-z)."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--submaps", default="150,600,2400",
                   help="archive sizes (comma-separated, increasing); 2400 is an hour of mapping")
    p.add_argument("--anchor-max", type=count(0), default=600,
                   help="time the former join-every-submap grid up to this size (it is quadratic)")
    p.add_argument("--voxel", type=number_in(1e-4, 100, unit=" m"), default=0.04, help="voxel edge, metres")
    p.add_argument("--max-depth", type=number_in(0, 1e4, low_open=True, unit=" m"), default=8.0,
                   help="depths beyond this are not kept, metres")
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--dir", help="write the archive here (default: a temporary folder, removed after)")
    p.add_argument("--json", action="store_true", help="print the result as JSON only")
    p.add_argument("--out", help="also write the JSON here")


def corridor_submap(index: int, rng: np.random.Generator, max_depth: float):
    """Submap `index` of the corridor: its five images' depths on the pixel grid, as the mapper keeps them."""
    from runtime.mapping.placement import ray_points
    from runtime.mapping.submap import Submap

    x0 = index * SPEED_M_S * SUBMAP_PERIOD_S
    xs = x0 + np.arange(5) * SPEED_M_S * 0.5
    off = STRIDE // 2
    v, u = np.mgrid[off:HEIGHT:STRIDE, off:WIDTH:STRIDE]
    u, v = u.ravel().astype(np.float64), v.ravel().astype(np.float64)
    ray_C = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=1)
    ray_W = ray_C @ R_WC.T                  # camera z = 1: the distance along a ray to its hit is the depth
    with np.errstate(divide="ignore"):
        t_y = np.where(ray_W[:, 1] > 0, CORRIDOR_Y, -CORRIDOR_Y) / ray_W[:, 1]
        t_z = np.where(ray_W[:, 2] > 0, CORRIDOR_Z[1] - 1.3, CORRIDOR_Z[0] - 1.3) / ray_W[:, 2]
    depth = np.minimum(np.abs(t_y), np.abs(t_z))
    keep = depth <= max_depth
    pts, image, T_SC = [], [], np.tile(np.eye(4), (5, 1, 1))
    for i in range(5):
        T_SC[i, 2, 3] = xs[i] - xs[2]       # along the optical axis of the centre image
        d = (depth[keep] * (1 + 0.02 * rng.standard_normal(int(keep.sum())))).astype(np.float32)
        pts.append(ray_points(d, K, u[keep], v[keep]))
        image.append(np.full(len(d), i, np.uint8))
    points_C = np.concatenate(pts)
    T_OS = np.eye(4)
    T_OS[:3, :3], T_OS[:3, 3] = R_WC, [xs[2], 0.0, 1.3]
    n = len(points_C)
    return Submap(index=index, frame_t_ns=np.int64(10**18) + (index * 3 + np.arange(5)) * 500_000_000,
                  centre=2, T_OS=T_OS, T_SC=T_SC, K=K.copy(), s_hat=1.0, frame_scales=np.ones(5),
                  points_C=points_C, image=np.concatenate(image), conf=np.ones(n, np.float32),
                  grey=rng.integers(0, 256, n).astype(np.uint8), T_MS=T_OS.copy(), lam=0.0,
                  version=index + 1, fit={})


def former_grid(voxel: float):
    """The anchor: `VoxelGrid` as it was before the twenty-sixth session, each call's sums joined to the grid
    at once by re-sorting the whole grid (concatenate, argsort, gather), only for adding points."""
    from runtime.mapping.fusion import VoxelGrid

    class FormerGrid(VoxelGrid):
        def integrate(self, points, grey=None, weights=None, sign=1) -> None:
            self._merge()
            sums = self.reduce(points, grey, weights, sign)
            if sums is None:
                return
            uk, add_w, add_p, add_g, add_n = sums
            pos, hit = self._locate(uk)
            self._add_at(pos, hit, add_w, add_p, add_g, add_n)
            new = ~hit
            if new.any():
                keys_all = np.concatenate([self._keys, uk[new]])
                order = np.argsort(keys_all, kind="stable")
                self._keys = keys_all[order]
                self._w = np.concatenate([self._w, add_w[new]])[order]
                self._wp = np.concatenate([self._wp, add_p[new]])[order]
                self._wg = np.concatenate([self._wg, add_g[new]])[order]
                self._n = np.concatenate([self._n, add_n[new]])[order]

    return FormerGrid(voxel)


def timed_fusion(folder: Path, voxel: float, former: bool) -> tuple[dict, tuple]:
    from runtime.mapping.fusion import VoxelGrid
    from tools.map_archive import fuse_archive

    tracemalloc.start()
    t0 = time.perf_counter()
    fused = fuse_archive(folder, voxel, verify=False, grid=former_grid(voxel) if former else VoxelGrid(voxel))
    seconds = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return {"seconds": seconds, "peak_mb": peak / 1e6, "voxels": int(len(fused[0]))}, fused


BENCH_MODEL = {"description": "bench"}
"""The model entry of the archives this benchmark writes: the mark of one it may replace."""


def _check_bench_folder(folder: Path) -> None:
    """ConfigError when `folder` (--dir's map/) exists and is not an archive this benchmark wrote: it
    replaced a run's real map with synthetic submaps."""
    from runtime.errors import ConfigError

    if not folder.exists() and not folder.is_symlink():
        return
    try:
        mine = json.loads((folder / "manifest.json").read_bytes()).get("model") == BENCH_MODEL
    except (OSError, ValueError, AttributeError):
        mine = False
    if not mine:
        raise ConfigError(f"--dir {folder.parent}: holds {folder.name}/, which this benchmark did not write "
                          "(a run's map archive?); it is not replaced: choose a new or empty folder")


def measure(sizes: list[int], anchor_max: int, voxel: float, max_depth: float, seed: int, folder: Path,
            progress: bool) -> list[dict]:
    from tools.map_archive import MapArchiveWriter

    rng = np.random.default_rng(seed)
    w = MapArchiveWriter(folder, {"rig": {"camera": "pinhole"}, "model": dict(BENCH_MODEL),
                                  "config": {"voxel_m": voxel}}, overwrite=True, views=False)
    rows, done, points = [], 0, 0
    for n in sizes:
        t0 = time.perf_counter()
        while done < n:
            sm = corridor_submap(done, rng, max_depth)
            points += sm.n_points
            w.commit([sm], [], done + 1, {})
            done += 1
            if progress and done % 200 == 0:
                print(f"  archived {done} / {sizes[-1]} submaps ({time.perf_counter() - t0:.0f} s)",
                      flush=True)
        w.close()
        row = {"submaps": n, "hours": n * SUBMAP_PERIOD_S / 3600, "points": points,
               "archive_mb": w.points_bytes / 1e6}
        if progress:
            print(f"  fusing {n} submaps", flush=True)
        row["grid"], fused = timed_fusion(folder, voxel, False)
        row["anchor"] = None
        if n <= anchor_max:
            if progress:
                print(f"  fusing {n} submaps, every submap joined at once (anchor)", flush=True)
            row["anchor"], ref = timed_fusion(folder, voxel, True)
            same = len(ref[0]) == len(fused[0]) and np.array_equal(ref[2], fused[2]) and \
                np.allclose(ref[0], fused[0], rtol=0, atol=1e-9) and np.array_equal(ref[1], fused[1])
            row["same_voxels"] = bool(same)
        rows.append(row)
    return rows


def _sizes(text: str) -> list[int]:
    try:
        sizes = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise SystemExit(f"davio bench map-export: --submaps must be integers, got {text!r}") from None
    if not sizes or any(s < 1 for s in sizes) or sizes != sorted(set(sizes)):
        raise SystemExit("davio bench map-export: --submaps must be increasing positive integers, "
                         f"got {text!r}")
    return sizes


def run(args: argparse.Namespace) -> int:
    sizes = _sizes(args.submaps)
    if not args.voxel > 0 or not args.max_depth > 0:
        raise SystemExit("davio bench map-export: --voxel and --max-depth must be positive")
    progress = not args.json
    if args.dir:
        _check_bench_folder(Path(args.dir) / "map")
        rows = measure(sizes, args.anchor_max, args.voxel, args.max_depth, args.seed, Path(args.dir) / "map",
                       progress)
    else:
        with tempfile.TemporaryDirectory(prefix="davio-map-export-") as tmp:
            rows = measure(sizes, args.anchor_max, args.voxel, args.max_depth, args.seed, Path(tmp) / "map",
                           progress)
    ok = all(r.get("same_voxels", True) for r in rows)
    out = {"voxel_m": args.voxel, "submap_period_s": SUBMAP_PERIOD_S, "rows": rows, "same_voxels": ok}
    if args.out:
        Path(args.out).write_text(strict_dumps(out, indent=1))
    if args.json:
        print(strict_dumps(out, indent=1))
        return 0 if ok else 1
    print("| submaps (hours) | points | archive MB | voxels | fusion s (ms a submap) | peak MB | "
          "former grid: fusion s (ms a submap) | peak MB | ratio |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        g, a = r["grid"], r["anchor"]
        former = "- | - | -" if a is None else (
            f"{a['seconds']:.1f} ({1e3 * a['seconds'] / r['submaps']:.0f}) | {a['peak_mb']:.0f} | "
            f"{g['seconds'] / a['seconds']:.2f}")
        print(f"| {r['submaps']} ({r['hours']:.2f} h) | {r['points']} | {r['archive_mb']:.0f} | "
              f"{g['voxels']} | {g['seconds']:.1f} ({1e3 * g['seconds'] / r['submaps']:.0f}) | "
              f"{g['peak_mb']:.0f} | {former} |")
    if not ok:
        print("ERROR: the two grids disagree", flush=True)
        return 1
    return 0
