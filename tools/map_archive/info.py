"""Summary of a map archive: submaps, points, extent in M, versions, integrity and size on disk."""
from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

from runtime.errors import DataError
from runtime.mapping.fusion import VoxelGrid
from tools.map_archive.export import main_segment, segment_sizes
from tools.map_archive.reader import has_view, integrity, load_submap, read_manifest, state_problem


def map_info(folder: str | Path, voxel_m: float | None = None) -> dict:
    """What the archive in `folder` holds.

    Points and the extent (axis-aligned box of every finite point in M, metres) come from placing the
    archived points with their manifest state; files that fail the integrity check are not loaded.

    Args:
        folder: the archive folder.
        voxel_m: also count fused voxels of this size (slower; each filter segment apart, as map.ply is
            fused: `voxels` is the main segment's, `voxels_by_segment` each one's); None skips it.

    Returns:
        dict with folder, format, schema_version, created_by, map_version, submaps, points,
        points_placed, extent ({"min", "max", "size"} or None), voxels (or None), node_versions
        ({version: submaps}), segments, segment_submaps ({segment: placeable submaps}), main_segment (the
        one map.ply, export and view use; None with one segment), voxels_by_segment, pairs, views
        (submaps storing a centre view, which `davio map align` and --prior-map need), journal
        (`read_manifest`), problems, orphans, bytes_on_disk.
    """
    folder = Path(folder)
    info = read_manifest(folder)
    problems, orphans = integrity(folder, info)
    bad = {p.split(":", 1)[0] for p in problems}
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    placed = views = 0
    grids: dict[int, VoxelGrid] = {}
    for e in info["submaps"]:
        if e["file"] in bad:
            continue
        try:
            sm = load_submap(folder, e)
        except DataError as exc:
            problems.append(str(exc))   # names the file
            continue
        views += has_view(folder, e)
        why = state_problem(e)
        if why is not None:
            problems.append(f"{e['file']}: its graph state in the manifest places no point ({why}): "
                            f"its {e['n_points']} points cannot be placed")
            continue
        pts = sm.points_M()
        finite = np.isfinite(pts).all(axis=1)
        if not finite.all():     # the writer keeps finite points only: the file holds NaN depths or poses
            problems.append(f"{e['file']}: {int((~finite).sum())} of its {len(pts)} points are not finite "
                            "(NaN or Inf depths or image poses in the file): they are left out")
        pts = pts[finite]
        if len(pts):
            lo, hi = np.minimum(lo, pts.min(axis=0)), np.maximum(hi, pts.max(axis=0))
            placed += len(pts)
            if voxel_m:
                grids.setdefault(int(e.get("segment", 0)), VoxelGrid(voxel_m)).integrate(pts)
    extent = None if placed == 0 else {"min": lo.tolist(), "max": hi.tolist(), "size": (hi - lo).tolist()}
    versions = Counter(int(e["version"]) for e in info["submaps"])
    sizes = segment_sizes(info["submaps"])
    main = main_segment(sizes) if len(sizes) > 1 else None
    by_segment = {str(s): len(g) for s, g in sorted(grids.items())} if voxel_m else None
    voxels = None if not voxel_m else (by_segment.get(str(main), 0) if main is not None
                                       else sum(by_segment.values()))
    return {
        "folder": str(folder), "format": info["format"], "schema_version": info["schema_version"],
        "created_by": info.get("created_by"), "map_version": info.get("map_version"),
        "submaps": len(info["submaps"]), "points": int(sum(int(e["n_points"]) for e in info["submaps"])),
        "points_placed": placed, "extent": extent, "voxels": voxels, "voxels_by_segment": by_segment,
        "node_versions": {str(v): versions[v] for v in sorted(versions)},
        "segments": len({int(e.get("segment", 0)) for e in info["submaps"]}),
        "segment_submaps": {str(s): n for s, n in sorted(sizes.items())}, "main_segment": main,
        "pairs": len(info.get("pairs") or []), "views": views, "journal": info["journal"],
        "problems": problems, "orphans": orphans,
        "bytes_on_disk": int(sum(p.stat().st_size for p in folder.iterdir() if p.is_file())),
    }
