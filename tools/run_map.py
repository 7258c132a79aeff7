"""The map outputs of a run: the `map/` archive checkpointed at every commit, and `map.ply`.

    map_out = MapOutput.create(out_dir, rig, model_desc, model, config)   # None when not mapping
    run_pipeline(..., map_sink=map_out.sink)
    summary = map_out.finish()     # exports map.ply from the archive; goes into report.json "map"
"""
from __future__ import annotations

import shutil
import sys
import threading
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

MIN_FREE_MB = 256.0
"""Free disk space (MB) the archive leaves for the rest of the run: below it the archive stops taking
commits, so that what is written at the end still fits: the trajectory files (about 5 MB an hour), the
report and map.ply (about 16 bytes a voxel: 256 MB hold 16 million). A submap's archive is about 0.9 MB
(0.23 MB of it the centre view, `mapping.archive_views`), 2.2 GB an hour."""


class MapOutput:
    """Writes a run's map archive as the mapper commits, and the final export.

    When the disk holding the run has less than `min_free_mb` free, the archive stops at its last commit
    (the folder stays a valid archive of the map so far); the commits skipped are counted, and the summary
    (report.json "map") and the console say so. The live map and the trajectory are not affected."""

    def __init__(self, out_dir: Path, header: dict, voxel_m: float, min_free_mb: float = MIN_FREE_MB,
                 views: bool = True) -> None:
        from tools.map_archive import MapArchiveWriter

        self.out_dir = Path(out_dir)
        self.voxel_m = voxel_m
        self.archive = MapArchiveWriter(self.out_dir / "map", header, overwrite=True, views=views)
        self.pairs: list[dict] = []
        self.min_free_mb = float(min_free_mb)
        self.stopped: dict | None = None
        """None, or why and where the archive stopped: reason, free_mb (None: a write failed),
        map_version, commits_skipped."""
        self.finished = False
        self._lock = threading.Lock()        # the model worker's commits against finish() on the main thread
        self.late_commits = 0
        """Commits that came after `finish` (a model call outliving the run's end): not archived."""

    @classmethod
    def create(cls, out_dir: Path, rig: Any, model_desc: str, model: Any, config: Any) -> MapOutput | None:
        """A MapOutput when the run maps (a model is given and mapping is enabled), else None."""
        if model is None or not config.mapping.enabled:
            return None
        from runtime.config_io import config_to_dict

        cam = rig.camera
        rig_d = {"camera": repr(cam), "width": cam.width, "height": cam.height, "K": cam.K.tolist(),
                 "T_IC": None if rig.T_IC is None else rig.T_IC.tolist(), "time_offset_s": rig.time_offset_s}
        model_d = {"description": model_desc, "K_rect": model.K_rect.tolist(), "class": type(model).__name__,
                   "emulated": "EMULATED" in model_desc}
        return cls(out_dir, {"rig": rig_d, "model": model_d, "config": config_to_dict(config)},
                   config.mapping.voxel_m, views=config.mapping.archive_views)

    def sink(self, commit: Any, stats: Any) -> None:
        """Checkpoint the archive at a map commit (called by the model worker). A commit the archive cannot
        write (a failing or read-only disk, the folder gone) stops it at its last whole commit, as a low
        disk does; after `finish` commits are counted, not written."""
        with self._lock:
            self._sink(commit, stats)

    def _sink(self, commit: Any, stats: Any) -> None:
        if self.finished:
            self.late_commits += 1
            return
        if self.stopped is None:
            free_mb = shutil.disk_usage(self.archive.folder).free / 1e6
            if free_mb < self.min_free_mb:
                self.stopped = {"reason": f"less than {self.min_free_mb:g} MB free on the run's disk",
                                "free_mb": round(free_mb, 1), "map_version": self.archive.map_version,
                                "commits_skipped": 0}
        if self.stopped is not None:
            self.stopped["commits_skipped"] += 1
            return
        pairs = self.pairs + ([commit.link.as_dict()] if commit.link is not None else [])
        version = self.archive.map_version      # the last whole commit, should this one fail part-way
        try:
            self.archive.commit([commit.submap, *commit.changed], pairs, commit.version, asdict(stats))
        except OSError as exc:
            where = f" {exc.filename}" if exc.filename else ""
            self.stopped = {"reason": f"the archive could not be written ({exc.strerror or exc}{where})",
                            "free_mb": None, "map_version": version, "commits_skipped": 1}
            print(f"davio: warning: the map archive stopped at map version {version}: "
                  f"{self.stopped['reason']}; the run goes on", file=sys.stderr)
            return
        self.pairs = pairs

    def finish(self) -> dict:
        """Export map.ply from the archive (every submap with its latest state; after a filter reset, the
        largest segment's: `choose_segment`); returns a summary whose paths are relative to the run
        folder (the run is written in `<out>.partial/` and renamed)."""
        from runtime.errors import DataError
        from tools.map_archive import export_map
        from tools.map_archive.export import choose_segment

        with self._lock:                      # a commit in progress ends first; later ones are counted
            self.finished = True
        n_sub = self.archive.n_submaps
        summary = {"archive": "map", "submaps": n_sub, "map_version": self.archive.map_version,
                   "ply": None, "voxels": 0, "archive_stopped": self.stopped, "archive_journal_left": None}
        try:
            self.archive.close()        # manifest.json whole, the journal removed
        except OSError as exc:          # the journal still brings the manifest up to date
            summary["archive_journal_left"] = f"manifest.json could not be written whole: {exc}"
            print(f"davio: warning: map/manifest.json was left with its journal ({exc}); the archive "
                  "reloads as it is", file=sys.stderr)
        summary["archive_written_mb"] = {"submaps": round(self.archive.points_bytes / 1e6, 3),
                                         "manifest": round(self.archive.bytes_written / 1e6, 3),
                                         "manifest_whole_writes": self.archive.whole_writes}
        summary["late_commits"] = self.late_commits
        if n_sub:
            try:
                segment, sizes = choose_segment(self.out_dir / "map", None)
                summary["ply_segment"] = segment
                summary["segment_submaps"] = {str(s): n for s, n in sorted(sizes.items())}
                summary["voxels"] = export_map(self.out_dir / "map", self.out_dir / "map.ply", self.voxel_m,
                                               ExportProgress(), verify=False,   # the archive just written
                                               segment=segment)[0]
                summary["ply"] = "map.ply"
            except (OSError, DataError) as exc:   # the trajectories and the report are still written
                where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
                summary["export_error"] = f"{where}{getattr(exc, 'strerror', None) or exc}"
                print(f"davio: warning: map.ply was not written ({summary['export_error']}); the archive in "
                      f"map/ holds the map: `davio map export RUN` writes it", file=sys.stderr)
        return summary


class ExportProgress:
    """Progress lines on stderr while the end of a run fuses its archive into map.ply, at most one every
    `every_s` seconds (a long run's export reads every submap again: minutes after hours of mapping)."""

    def __init__(self, every_s: float = 5.0) -> None:
        self.every_s = every_s
        self.t0 = self.last = time.monotonic()

    def __call__(self, done: int, total: int) -> None:
        now = time.monotonic()
        if now - self.last >= self.every_s and done < total:
            self.last = now
            print(f"  exporting map.ply: {done}/{total} submaps fused ({now - self.t0:.0f} s)",
                  file=sys.stderr, flush=True)
