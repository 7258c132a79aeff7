"""Final re-export: every archived submap placed with its latest graph state, fused, written as PLY."""
from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from pathlib import Path

import numpy as np

from runtime.errors import DataError
from runtime.files import atomic_write_bytes
from runtime.mapping.fusion import VoxelGrid
from tools.map_archive.reader import integrity, iter_submaps, read_manifest, state_is_usable


def fuse_archive(folder: str | Path, voxel_m: float = 0.04,
                 progress: Callable[[int, int], None] | None = None, skip_damaged: bool = False,
                 notes: list[str] | None = None, verify: bool = True, T_out: np.ndarray | None = None,
                 grid: VoxelGrid | None = None, segment: int | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fuse every submap of the archive at its manifest state (eq. placement) into voxels.

    Each voxel holds the unweighted mean of the points that fall in it. Every file is first checked
    against the manifest (size and sha256, as `davio map info`): a damaged or missing file is a DataError
    naming it, unless `skip_damaged`, which leaves those submaps out. A submap whose graph state was
    written as null (not finite) cannot be placed and is left out. Whatever is left out is said in `notes`.

    Args:
        folder: the archive folder.
        voxel_m: voxel edge length, metres.
        progress: called with (submaps done, submaps total) after each submap.
        skip_damaged: leave out the submaps whose files fail the integrity check instead of refusing.
        notes: when given, one line is appended per kind of submap left out.
        verify: check every file's size and sha256 first (False: the run exporting the archive it has
            just written skips that second read of every file).
        T_out: (4,4) moves the map frame M into another frame before fusion (e.g. a prior map's, T_PN
            of `davio map align`); None keeps M.
        grid: fuse into this grid (which may already hold another archive's points) instead of a new one.
        segment: only the submaps of this filter segment (a transform such as T_PN holds for one
            segment's map frame); the others are left out and said in `notes`. None: every submap.

    Returns:
        (points (V,3) float64 in M (or T_out's frame), grey (V,) uint8, counts (V,) int64 points per voxel)
        of the whole grid.
    """
    info = read_manifest(folder)
    problems = integrity(folder, info)[0] if verify else []
    damaged = {p.split(":", 1)[0] for p in problems}
    if problems and not skip_damaged:
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        raise DataError(f"damaged archive: {problems[0]}{more}; `davio map info` lists every problem, "
                        "--skip-damaged leaves those submaps out", folder)
    entries = [e for e in info["submaps"] if e["file"] not in damaged]
    if segment is not None:
        other = [e for e in entries if int(e.get("segment", 0)) != int(segment)]
        entries = [e for e in entries if int(e.get("segment", 0)) == int(segment)]
        if other and notes is not None:
            notes.append(f"{folder}: {len(other)} submap(s) of other filter segments left out (each segment "
                         f"has its own frame; segment {segment} is used)")
    unplaced = [e for e in entries if not state_is_usable(e)]
    entries = [e for e in entries if state_is_usable(e)]
    if notes is not None:
        if damaged:
            notes.append(f"{len(damaged)} damaged submap file(s) left out: {', '.join(sorted(damaged))}")
        if unplaced:
            notes.append(f"{len(unplaced)} submap(s) whose graph state places no point (not finite, or "
                         "not a rigid transform: `davio map info` says which) left out "
                         f"({sum(int(e['n_points']) for e in unplaced)} points): "
                         f"{', '.join(e['file'] for e in unplaced)}")
    total = len(entries)
    grid = VoxelGrid(voxel_m) if grid is None else grid
    not_finite: dict[str, int] = {}
    files = {int(e["index"]): str(e["file"]) for e in entries}
    for k, sm in enumerate(iter_submaps(folder, {**info, "submaps": entries}), start=1):
        pts = sm.points_M()
        if T_out is not None:
            pts = pts @ np.asarray(T_out, np.float64)[:3, :3].T + np.asarray(T_out, np.float64)[:3, 3]
        ok = np.isfinite(pts).all(axis=1)
        if not ok.all():
            not_finite[files[sm.index]] = int((~ok).sum())
        grid.integrate(pts[ok], sm.grey[ok])
        if progress is not None:
            progress(k, total)
    if not_finite and notes is not None:
        notes.append(f"{sum(not_finite.values())} points that are not finite left out (NaN or Inf depths or "
                     f"image poses in {', '.join(sorted(not_finite))}; `davio map info` lists them)")
    return grid.points()


def segment_sizes(entries: list[dict]) -> Counter:
    """Placeable submaps (`state_is_usable`) per filter segment of manifest entries; a segment whose
    submaps are all unplaceable counts 0."""
    sizes = Counter({int(e.get("segment", 0)): 0 for e in entries})
    sizes.update(int(e.get("segment", 0)) for e in entries if state_is_usable(e))
    return sizes


def main_segment(sizes: Counter) -> int:
    """The filter segment a map of several is shown by default (`sizes`: placeable submaps per segment,
    `segment_sizes`): the one with the most, the earliest on a tie. Each segment (after a filter reset)
    has its own odometry and map frame, so fusing them together would overlay unrelated maps."""
    return max(sizes, key=lambda s: (sizes[s], -s))


def choose_segment(folder: str | Path, segment: int | None, notes: list[str] | None = None
                   ) -> tuple[int | None, Counter]:
    """(the segment to fuse: `segment`, else the main one when the archive holds several (said in `notes`),
    else None (one segment: every submap); placeable submaps per segment). DataError naming the segments
    when `segment` is not one of them."""
    sizes = segment_sizes(read_manifest(folder)["submaps"])
    listed = ", ".join(f"{s} ({n} submaps)" for s, n in sorted(sizes.items()))
    if segment is not None:
        if segment not in sizes:
            raise DataError(f"the archive holds no submap of filter segment {segment} (segments: "
                            f"{listed or 'none'})", folder)
        return int(segment), sizes
    if len(sizes) < 2:
        return None, sizes
    main = main_segment(sizes)
    if notes is not None:
        notes.append(f"the map holds {len(sizes)} filter segments, each in its own frame (the filter was "
                     f"reset): {listed}; segment {main}, the largest, is used (--segment K picks another)")
    return main, sizes


def write_ply(path: str | Path, points: np.ndarray, grey: np.ndarray, comments: tuple[str, ...] = ()) -> None:
    """Write a binary little-endian PLY: float x, y, z and uchar red, green, blue (= grey), atomically;
    `comments`: header lines after "comment davio map" (e.g. "segment 2": the filter segment it holds)."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    g = np.asarray(grey).reshape(-1)
    if g.shape[0] != pts.shape[0]:
        raise ValueError(f"{pts.shape[0]} points but {g.shape[0]} grey values")
    rows = np.empty(len(pts), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                     ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    for a, name in enumerate("xyz"):
        rows[name] = pts[:, a]
    g8 = np.clip(g, 0, 255).astype(np.uint8)
    rows["red"], rows["green"], rows["blue"] = g8, g8, g8
    header = ("ply\nformat binary_little_endian 1.0\ncomment davio map\n"
              + "".join(f"comment {c}\n" for c in comments)
              + f"element vertex {len(pts)}\n"
              "property float x\nproperty float y\nproperty float z\n"
              "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n")
    atomic_write_bytes(Path(path), header.encode("ascii") + rows.tobytes())


def supported(fused: tuple[np.ndarray, np.ndarray, np.ndarray], min_points: int
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The voxels of `fuse_archive`'s result that hold at least `min_points` fused points.

    A far surface's points are sparse, so a voxel there often holds one point of one image; keeping only
    voxels with more support trades recall for precision (BENCHMARKS.md "Dense mapping": the trade
    depends on the scene, so 1, keeping every voxel, is the default).
    """
    if min_points < 1:
        raise ValueError(f"min_points must be >= 1, got {min_points}")
    points, grey, counts = fused
    keep = counts >= min_points
    return points[keep], grey[keep], counts[keep]


def empty_reason(fused: int, min_points: int, notes: list[str] | None) -> str:
    """Why an export or view has no voxel to show."""
    if fused:
        return f"nothing to export: none of the {fused} fused voxels holds {min_points} or more points"
    why = "; ".join(notes or []) or "the archive holds no placed point"
    return f"nothing to export: no submap could be fused ({why})"


def export_map(folder: str | Path, out_ply: str | Path, voxel_m: float = 0.04,
               progress: Callable[[int, int], None] | None = None, min_points: int = 1,
               skip_damaged: bool = False, notes: list[str] | None = None, verify: bool = True,
               T_out: np.ndarray | None = None, merge_with: str | Path | None = None,
               segment: int | None = None, merge_segment: int | None = None,
               refuse_empty: bool = False) -> tuple[int, int]:
    """Fuse the archive in `folder` (`fuse_archive`, moved by `T_out` when given) and write the voxels
    holding at least `min_points` points to `out_ply`; with `merge_with`, that archive (in its own frame,
    which T_out must lead to) is fused into the same voxels first. `segment` / `merge_segment` keep only
    that filter segment of each archive (`fuse_archive`). `refuse_empty`: no voxel to write is a DataError
    and `out_ply` is left as it was (a re-export must not replace a map with nothing). Returns (voxels
    written, voxels fused)."""
    grid = VoxelGrid(voxel_m)
    if merge_with is not None:
        fuse_archive(merge_with, voxel_m, progress, skip_damaged, notes, verify, grid=grid,
                     segment=merge_segment)
    fused = fuse_archive(folder, voxel_m, progress, skip_damaged, notes, verify, T_out=T_out, grid=grid,
                         segment=segment)
    points, grey, _ = supported(fused, min_points)
    if refuse_empty and not len(points):
        raise DataError(empty_reason(len(fused[0]), min_points, notes), folder)
    # the segment a run's map.ply holds (`davio eval surface` checks a trajectory against it); merged maps
    # hold two archives' segments and say nothing
    if segment is None and merge_with is None:     # an archive of one segment (of a run reset maybe later)
        only = segment_sizes(read_manifest(folder)["submaps"])
        segment = next(iter(only)) if len(only) == 1 else None
    said = () if segment is None or merge_with is not None else (f"segment {segment}",)
    write_ply(out_ply, points, grey, said)
    return int(len(points)), int(len(fused[0]))
