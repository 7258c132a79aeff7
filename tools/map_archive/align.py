"""Aligning two map archives of one place (`davio map align NEW --to PRIOR`): the transform from the new
session's map frame to the prior one's, from the centre views stored with the submaps
(runtime/graph/relocalize.py), and the new run's trajectory moved into the prior frame."""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from runtime.errors import DataError
from runtime.graph.relocalize import AlignConfig, Alignment, PlaceView, PriorMapLocalizer, align_sessions
from tools.map_archive.export import main_segment, segment_sizes
from tools.map_archive.reader import integrity, load_view, read_manifest, state_is_usable

MAX_VIEWS = 600
"""Views loaded from one archive at most (as many as the revisits keep archived): about 140 MB with
float16 descriptors; a longer map is subsampled evenly, and the notes say so."""


def load_place_views(archive: Path, notes: list[str], max_views: int = MAX_VIEWS
                     ) -> tuple[list[PlaceView], int, int]:
    """(the centre views of the archive's largest filter segment with their final map poses, that
    segment, the number of segments). Descriptors stay float16 as stored (`match_views` expands them per
    match). Submaps of other segments (another odometry frame after a filter reset), with a non-finite
    state or without a stored view are left out, and beyond `max_views` views every k-th is kept; each
    said in `notes`.

    Raises:
        DataError: a damaged archive (naming the file), or one that holds no centre view at all.
    """
    info = read_manifest(archive)
    problems, _ = integrity(archive, info)
    if problems:
        raise DataError(f"damaged archive: {problems[0]}" + (f" (and {len(problems) - 1} more)"
                                                             if len(problems) > 1 else ""), archive)
    entries = [e for e in info["submaps"] if state_is_usable(e)]
    if len(entries) < len(info["submaps"]):
        notes.append(f"{archive}: {len(info['submaps']) - len(entries)} submap(s) whose graph state places "
                     "no point (not finite, or not a rigid transform) left out")
    if not entries:
        raise DataError("the archive holds no submap whose graph state places its points (finite, rigid)",
                        archive)
    segments = segment_sizes(entries)
    segment = main_segment(segments)
    if len(segments) > 1:
        notes.append(f"{archive}: {len(segments)} filter segments (each its own odometry frame); segment "
                     f"{segment}, the largest ({segments[segment]} submaps), is aligned")
    views: list[PlaceView] = []
    missing = 0
    chosen = sorted((e for e in entries if int(e.get("segment", 0)) == segment),
                    key=lambda e: int(e["index"]))
    if len(chosen) > max_views:
        keep = np.unique(np.linspace(0, len(chosen) - 1, max_views).round().astype(int))
        notes.append(f"{archive}: {len(chosen)} submaps; {len(keep)} of their views, evenly spaced, are used "
                     f"(at most {max_views})")
        chosen = [chosen[k] for k in keep]
    for e in chosen:
        fv = load_view(archive, e, compact=True)
        if fv is None:
            missing += 1
            continue
        views.append(PlaceView(int(e["index"]), np.array(e["T_MS"], np.float64), fv[0], fv[1]))
    if not views:
        raise DataError("the archive stores no centre views, which alignment needs: it was written before "
                        "davio stored them, with the submap graph off (mapping.graph = false) or with "
                        "mapping.archive_views = false; run the recording again to align it", archive)
    if missing:
        notes.append(f"{archive}: {missing} submap(s) of segment {segment} without a stored view left out")
    return views, segment, len(segments)


def prior_map_localizer(folder: Path, notes: list[str], cfg: AlignConfig | None = None) -> PriorMapLocalizer:
    """A `PriorMapLocalizer` over the map of an earlier run (a run folder holding map/, or map/ itself):
    its largest segment's centre views at their final poses. DataError naming the folder when it holds
    no map, a damaged one, or one without views."""
    folder = Path(folder)
    archive = folder / "map" if (folder / "map").is_dir() else folder
    views, segment, _ = load_place_views(archive, notes)
    loc = PriorMapLocalizer(views, match_views, cfg, source=str(archive.resolve()))
    loc.prior_segment = segment
    loc.prior_id = archive_id(archive)     # as loaded: the archive may be replaced while the run goes on
    return loc


def match_views(fa, fb) -> tuple[np.ndarray, np.ndarray]:
    """(idx_a, idx_b) of two views' stored features (float16 descriptors expanded for the match)."""
    from models.matcher.matcher import match_stored
    from runtime.graph.views import expanded_features

    m = match_stored(expanded_features(fa), expanded_features(fb))
    return m.idx_a, m.idx_b


def archive_id(folder: Path) -> str | None:
    """The archive's id (manifest "archive_id"; None for an archive written before davio recorded one)."""
    value = read_manifest(folder).get("archive_id")
    return value if isinstance(value, str) else None


def align_archives(new: Path, prior: Path, cfg: AlignConfig | None = None,
                   progress: Callable[[int, int], None] | None = None) -> tuple[Alignment, dict, list[str]]:
    """(the alignment of archive `new` to archive `prior`, a JSON-ready summary, notes)."""
    notes: list[str] = []
    prior_views, prior_segment, _ = load_place_views(prior, notes)
    new_views, new_segment, new_segments = load_place_views(new, notes)
    cfg = cfg or AlignConfig()
    res = align_sessions(prior_views, new_views, match_views, cfg, progress)
    summary = {"format": "davio-alignment", "prior": str(Path(prior).resolve()),
               "new": str(Path(new).resolve()),
               "prior_id": archive_id(prior), "new_id": archive_id(new),
               "prior_segment": prior_segment, "new_segment": new_segment, "new_segments": new_segments,
               "frames": "T_PN maps points of the new map frame into the prior one: x_P = T_PN x_N",
               "settings": {"candidates_per_view": cfg.candidates_per_view, "min_views": cfg.min_views,
                            "agree_m": cfg.agree_m, "agree_deg": cfg.agree_deg,
                            "max_tilt_deg": cfg.max_tilt_deg, "words": cfg.words},
               **res.as_dict()}
    return res, summary, notes


def transform_tum(src: Path, dst: Path, T_PN: np.ndarray) -> int:
    """Write TUM file `src` (poses T_NI in the new map frame) to `dst` with every pose moved into the
    prior frame, T_PI = T_PN T_NI. Returns the number of poses."""
    from drivers.trajectory_files import read_tum
    from runtime.geometry.trajectory import PoseTrajectory
    from tools.evaluation.trajectory_io import write_tum

    traj = read_tum(src)
    if not len(traj):
        raise DataError("no poses", src)
    T = np.asarray(T_PN, np.float64)
    moved = PoseTrajectory(traj.t_ns, traj.p @ T[:3, :3].T + T[:3, 3], T[:3, :3] @ traj.R)
    write_tum(dst, moved)
    return len(traj)
