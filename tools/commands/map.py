"""`davio map info|export|view|align D`: inspect, re-export and picture a run's map archive, and
localise it in an earlier run's map of the same place.

D is a run folder holding `map/`, or the `map/` folder itself.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from runtime.errors import ConfigError, DataError
from runtime.json_out import strict_dumps
from tools.cli_types import count, number

NAME = "map"
HELP = "inspect, re-export (PLY), picture or align a run's map archive"


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="map_command", metavar="ACTION")
    folder_help = "a run folder holding map/, or the map/ folder itself"
    fmt = argparse.ArgumentDefaultsHelpFormatter
    pi = sub.add_parser("info", help="submaps, points, extent, versions and integrity (exit 1 if damaged)",
                        formatter_class=fmt)
    pi.add_argument("folder", type=Path, help=folder_help)
    pi.add_argument("--json", action="store_true", help="print the summary as JSON")
    pi.add_argument("--voxel", type=number, default=None,
                    help="also count the fused voxels of this edge length (m; slower)")
    pe = sub.add_parser("export", help="fuse every submap at its latest graph state and write a PLY",
                        formatter_class=fmt)
    pe.add_argument("folder", type=Path, help=folder_help)
    pe.add_argument("--voxel", type=number, default=0.04, help="voxel edge length (m)")
    pe.add_argument("--out", type=Path, default=None,
                    help="PLY file, or a folder to write map.ply in (default: map.ply in the run folder)")
    pe.add_argument("--min-points", type=count(1), default=1,
                    help="write only voxels holding at least this many fused depth samples (2 or more drops "
                         "isolated far-range samples: a cleaner but less complete map)")
    pe.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    pe.add_argument("--skip-damaged", action="store_true",
                    help="leave out submaps whose files fail the integrity check (default: refuse)")
    pe.add_argument("--segment", type=count(0), default=None, metavar="K",
                    help="filter segment to use (after a filter reset each segment's map has its own "
                         "frame); default: the largest when there are several (as the run's map.ply)")
    frame = pe.add_mutually_exclusive_group()
    frame.add_argument("--in-prior", action="store_true",
                       help="the map moved into the frame of the earlier run it was aligned to (the run's "
                            "alignment.json, from --prior-map or `davio map align`); default out "
                            "map.prior.ply")
    frame.add_argument("--merge-prior", action="store_true",
                       help="as --in-prior, fused into one map with the earlier run's own map; default out "
                            "map.merged.ply")
    pv = sub.add_parser("view", help="a PNG with a top and an oblique view coloured by height",
                        formatter_class=fmt)
    pv.add_argument("folder", type=Path, help=folder_help)
    pv.add_argument("--voxel", type=number, default=0.04, help="voxel edge length (m) of the fused cloud")
    pv.add_argument("--out", type=Path, default=None,
                    help="PNG file, or a folder to write map.png in (default: map.png in the run folder)")
    pv.add_argument("--min-points", type=count(1), default=1,
                    help="show only voxels holding at least this many fused depth samples")
    pv.add_argument("--interactive", action="store_true", help="also open open3d's viewer (needs a display)")
    pv.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    pv.add_argument("--skip-damaged", action="store_true",
                    help="leave out submaps whose files fail the integrity check (default: refuse)")
    pv.add_argument("--segment", type=count(0), default=None, metavar="K",
                    help="filter segment to use (after a filter reset each segment's map has its own "
                         "frame); default: the largest when there are several (as the run's map.ply)")


    pa = sub.add_parser("align", help="localise a run's map in an earlier run's map of the same place: the "
                        "yaw and translation between their map frames (exit 1 when not localised)",
                        formatter_class=fmt)
    pa.add_argument("folder", type=Path, help="the new run: " + folder_help)
    pa.add_argument("--to", dest="prior", type=Path, required=True,
                    help="the earlier run whose map frame the new one is put in: " + folder_help)
    pa.add_argument("--out", type=Path, default=None,
                    help="the alignment JSON (default: alignment.json in the new run's folder); the new "
                         "run's final.tum moved into the prior frame is written beside it as "
                         "final.prior.tum")
    pa.add_argument("--candidates", type=count(1), default=5,
                    help="prior views verified per new view, ranked by appearance")
    pa.add_argument("--min-views", type=count(1), default=3,
                    help="distinct new views that must agree on the transform")
    pa.add_argument("--json", action="store_true", help="print the alignment as JSON")
    pa.add_argument("--overwrite", action="store_true", help="replace an existing --out file")


def resolve(folder: Path) -> tuple[Path, Path]:
    """(archive folder, run folder) of D: D/map when it is a folder, else D itself (run folder = parent).

    Raises DataError for a run folder (or a folder without an archive) that holds no map/."""
    from runtime.errors import DataError
    from tools.map_archive.format import MANIFEST_NAME
    from tools.run_folder import RUN_MARKERS

    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise DataError("not a folder: give the run folder (or its map/ archive folder)", folder)
    if (folder / "map").is_dir():
        return folder / "map", folder
    if folder.is_dir() and not (folder / MANIFEST_NAME).exists() and any((folder / m).exists()
                                                                          for m in RUN_MARKERS):
        raise DataError("run folder without a map/: the run was made without a depth model (--native-only) "
                        "or with --no-map, or stopped before its first map commit", folder)
    return folder, folder.parent


class _Progress:
    """Progress lines on stderr, at most one a second (long exports only)."""

    def __init__(self, what: str) -> None:
        self.what, self.t0, self.last = what, time.monotonic(), time.monotonic()

    def __call__(self, done: int, total: int) -> None:
        now = time.monotonic()
        if now - self.last >= 1.0:
            self.last = now
            print(f"davio map {self.what}: {done}/{total} submaps fused ({now - self.t0:.0f} s)",
                  file=sys.stderr, flush=True)


def output_path(out: Path | None, run_folder: Path, name: str) -> Path:
    """--out as given, `name` inside it when it is an existing folder, or `name` in the run folder."""
    if out is None:
        return run_folder / name
    return out / name if out.is_dir() else out


def checked_output(args: argparse.Namespace, archive: Path, run_folder: Path, name: str) -> tuple[Path, bool]:
    """(the output file, whether it replaces an existing one) after `check_output_file`: the run's own
    map.ply / map.png may be replaced by default, any other existing file only with --overwrite."""
    from tools.output_file import check_output_file

    out = output_path(args.out, run_folder, name)
    own = args.out is None and archive == run_folder / "map"
    replaced = check_output_file(out, "--out", (Path(name).suffix,), overwrite=args.overwrite,
                                 replaceable=own, protected_dirs=[archive])
    return out, replaced


def _reading(exc: OSError, out: Path) -> bool:
    """Whether an OSError of an export names a file other than the output (or the temporary beside it):
    an input that cannot be read, not an output that cannot be written."""
    if exc.filename is None:
        return False
    name = Path(exc.filename)
    return not (name.parent.resolve() == out.parent.resolve() and out.name in name.name)


def _check_fuse_args(voxel: float, min_points: int = 1) -> None:
    from runtime.mapping.config import MAX_VOXEL_M, MIN_VOXEL_M

    if not MIN_VOXEL_M <= voxel <= MAX_VOXEL_M:
        raise ConfigError(f"--voxel must be an edge length from {MIN_VOXEL_M} to {MAX_VOXEL_M} m, "
                          f"got {voxel}")
    if min_points < 1:
        raise ConfigError(f"--min-points must be at least 1, got {min_points}")


def _print_notes(what: str, notes: list[str]) -> None:
    for line in notes:
        print(f"davio map {what}: note: {line}", file=sys.stderr)


def _print_info(info: dict) -> None:
    print(f"map archive  {info['folder']}")
    print(f"format       {info['format']} schema {info['schema_version']} ({info['created_by']})")
    print(f"map version  {info['map_version']}")
    print(f"submaps      {info['submaps']} in {info['segments']} segment(s), {info['pairs']} pairs")
    if info.get("main_segment") is not None:
        sizes = ", ".join(f"{s} ({n} placeable)" for s, n in info["segment_submaps"].items())
        print(f"segments     {sizes}: each in its own frame (the filter was reset); map.ply, export and view "
              f"use segment {info['main_segment']} (--segment K another)")
    print(f"points       {info['points']} ({info['points_placed']} placed)")
    print(f"views        {info['views']} of {info['submaps']} submaps keep their centre view"
          + (" (what `davio map align` and --prior-map match)" if info["views"] else
             " (this map cannot be aligned: written before davio kept them, without the submap graph, or "
             "with mapping.archive_views = false)"))
    ext = info["extent"]
    if ext:
        lo, hi, sz = (" ".join(f"{v:.2f}" for v in ext[k]) for k in ("min", "max", "size"))
        print(f"extent [m]   min {lo}  max {hi}  size {sz}")
    else:
        print("extent [m]   (no points)")
    vers = ", ".join(f"v{v}: {n}" for v, n in info["node_versions"].items()) or "-"
    print(f"node versions {vers}")
    if info["voxels"] is not None:
        by = info.get("voxels_by_segment") or {}
        print(f"voxels       {info['voxels']}" + (f" (segment {info['main_segment']}; by segment: "
                                                  + ", ".join(f"{s}: {n}" for s, n in by.items()) + ")"
                                                  if info.get("main_segment") is not None else ""))
    print(f"on disk      {info['bytes_on_disk'] / 1e6:.2f} MB")
    j = info["journal"]
    if j["commits"] or j["incomplete_bytes"]:
        print(f"journal      {j['commits']} commit(s) since manifest.json was last written whole (a run is "
              "writing this archive, or stopped before its end)"
              + (f"; a last commit cut short ({j['incomplete_bytes']} bytes) was left out"
                 if j["incomplete_bytes"] else ""))
    if info["problems"]:
        print(f"integrity    {len(info['problems'])} problem(s):")
        for line in info["problems"]:
            print(f"  {line}")
    else:
        print("integrity    ok")
    for line in info["orphans"]:
        print(f"  note: {line}")


def run(args: argparse.Namespace) -> int:
    action = getattr(args, "map_command", None)
    if action is None:
        print("davio map: name an action: info, export, view, align")
        return 2
    archive, run_folder = resolve(args.folder)
    if action == "align":
        from tools.map_alignment_files import align

        return align(args, archive, run_folder)
    if action == "info":
        from tools.map_archive.info import map_info

        if args.voxel is not None:
            _check_fuse_args(args.voxel)
        info = map_info(archive, args.voxel)
        if args.json:
            print(strict_dumps(info, indent=2))
        else:
            _print_info(info)
        return 1 if info["problems"] else 0
    if action == "export":
        from tools.map_archive.export import choose_segment, export_map

        _check_fuse_args(args.voxel, args.min_points)
        from tools.map_alignment_files import read_alignment

        T_out, prior, seg, prior_seg = (read_alignment(run_folder, args.merge_prior, archive)
                                        if args.in_prior or args.merge_prior else (None, None, None, None))
        aligned = args.in_prior or args.merge_prior
        if aligned and args.segment is not None and args.segment != seg:
            raise ConfigError(f"--segment {args.segment}: the alignment to the prior map holds for "
                              + (f"segment {seg} (the one `davio map align` aligned)" if seg is not None else
                                 "the segment it was fitted on, which its alignment.json (from an older "
                                 "davio) does not name: align the run again"))
        name = "map.merged.ply" if args.merge_prior else "map.prior.ply" if args.in_prior else "map.ply"
        out, replaced = checked_output(args, archive, run_folder, name)
        t0 = time.monotonic()
        notes: list[str] = []
        if seg is None:
            seg = choose_segment(archive, args.segment, notes)[0]
        if args.merge_prior and prior_seg is None:
            prior_seg = choose_segment(prior, None, notes)[0]
        try:
            n, fused = export_map(archive, out, args.voxel, _Progress("export"), args.min_points,
                                  args.skip_damaged, notes, T_out=T_out,
                                  merge_with=prior if args.merge_prior else None, segment=seg,
                                  merge_segment=prior_seg, refuse_empty=True)
        except OSError as exc:
            if _reading(exc, out):
                raise DataError(f"cannot read {exc.filename} ({exc.strerror or exc})") from None
            raise ConfigError(f"--out {out}: cannot write ({exc.strerror or exc})") from None
        except DataError:
            _print_notes("export", notes)        # what was left out, before why nothing was written
            raise
        _print_notes("export", notes)
        dropped = (f" ({fused - n} of {fused} with fewer than {args.min_points} samples left out)"
                   if args.min_points > 1 else "")
        print(f"davio map export: {n} voxels ({args.voxel} m){dropped} -> {out}"
              f"{' (replaced)' if replaced else ''} in {time.monotonic() - t0:.1f} s")
        return 0
    from tools.map_archive.export import choose_segment, empty_reason, fuse_archive, supported
    from tools.map_archive.view import interactive, render_views

    _check_fuse_args(args.voxel, args.min_points)
    out, replaced = checked_output(args, archive, run_folder, "map.png")
    notes: list[str] = []
    segment = choose_segment(archive, args.segment, notes)[0]
    fused = fuse_archive(archive, args.voxel, _Progress("view"), args.skip_damaged, notes, segment=segment)
    points, grey, _ = supported(fused, args.min_points)
    _print_notes("view", notes)
    if not len(points):
        raise DataError(empty_reason(len(fused[0]), args.min_points, notes).replace("export", "draw", 1),
                        archive)
    try:
        render_views(points, grey, out)
    except OSError as exc:
        raise ConfigError(f"--out {out}: cannot write ({exc.strerror or exc})") from None
    print(f"davio map view: {len(points)} voxels -> {out}{' (replaced)' if replaced else ''}")
    if args.interactive:
        why = interactive(points, grey)
        if why:
            print(f"davio map view: no interactive viewer: {why}", file=sys.stderr)
    return 0


