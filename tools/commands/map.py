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


def _prior_alignment(run_folder: Path, merge: bool, archive: Path | None = None) -> tuple:
    """(T_PN (4,4), the prior archive, the new map's aligned segment, the prior map's segment) from the
    run folder's alignment.json (segments None when it does not say); ConfigError when there is none, it
    did not localise, or (for merging) its prior map is gone."""
    import json

    import numpy as np

    from calib.rig import rigid_problem

    path = run_folder / "alignment.json"
    if not path.is_file():
        raise ConfigError(f"{path} not found: align the run first (`davio map align {run_folder} --to "
                          "PRIOR`; a run made with --prior-map writes it only once it localised)")
    try:
        al = json.loads(path.read_text())
        T = np.array(al["T_PN"], np.float64) if al.get("T_PN") is not None else None
        prior = Path(al["prior"])
        segments = (al.get("new_segment"), al.get("prior_segment"))
    except (OSError, ValueError, KeyError, TypeError, AttributeError, RecursionError, OverflowError) as exc:
        raise ConfigError(f"{path}: not a davio alignment ({type(exc).__name__}: {exc})") from None
    if al.get("localized") is not True:
        raise ConfigError(f"{path}: the run was not localised in the prior map ({al.get('reason')})")
    problem = "missing" if T is None else rigid_problem(T)
    if problem is not None:
        raise ConfigError(f"{path}: T_PN {problem} (an edited or damaged file): align the run again")
    if any(not (v is None or (isinstance(v, int) and not isinstance(v, bool))) for v in segments):
        raise ConfigError(f"{path}: new_segment and prior_segment must be integers, got "
                          f"{segments[0]!r}, {segments[1]!r}")
    _check_aligned_maps(path, al, archive if archive is not None else run_folder / "map", prior)
    if merge and not (prior / "manifest.json").is_file():
        raise ConfigError(f"{path} names the prior map {prior}, which is gone (no manifest.json there)")
    return T, prior, *segments


def _reading(exc: OSError, out: Path) -> bool:
    """Whether an OSError of an export names a file other than the output (or the temporary beside it):
    an input that cannot be read, not an output that cannot be written."""
    if exc.filename is None:
        return False
    name = Path(exc.filename)
    return not (name.parent.resolve() == out.parent.resolve() and out.name in name.name)


def _check_aligned_maps(path: Path, al: dict, own: Path, prior: Path) -> None:
    """ConfigError when the maps are not the ones aligned: the prior was replaced at its path since, or the
    alignment was written for another run's map (`davio map align X --out THIS_RUN`). An alignment of an
    older davio records no ids: taken as it is."""
    from tools.map_archive.align import archive_id

    def id_of(folder: Path) -> str | None:
        try:
            return archive_id(folder) if (folder / "manifest.json").is_file() else None
        except DataError:          # a damaged archive: the export itself says what is wrong with it
            return None

    if isinstance(al.get("new_id"), str) and id_of(own) not in (None, al["new_id"]):
        raise ConfigError(f"{path} aligns another map ({al.get('new')}), not this run's: align this run "
                          f"(`davio map align {own.parent} --to PRIOR`)")
    if isinstance(al.get("prior_id"), str) and id_of(prior) not in (None, al["prior_id"]):
        raise ConfigError(f"{prior} is not the map this run was aligned to (it was replaced since: its "
                          f"archive id differs): align the run again")


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
        return _align(args, archive, run_folder)
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
        T_out, prior, seg, prior_seg = (_prior_alignment(run_folder, args.merge_prior, archive)
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


def _align(args: argparse.Namespace, archive: Path, run_folder: Path) -> int:
    from runtime.files import atomic_write_text
    from runtime.graph.relocalize import AlignConfig
    from tools.map_archive.align import align_archives, transform_tum
    from tools.output_file import check_output_file

    cfg = AlignConfig(candidates_per_view=args.candidates, min_views=args.min_views)
    prior_archive, _ = resolve(args.prior)
    if prior_archive.resolve() == archive.resolve():
        raise ConfigError("--to names the same map as the new run; give an earlier run of the same place")
    out = output_path(args.out, run_folder, "alignment.json")
    in_run = archive == run_folder / "map"            # a run folder's archive: its final.tum belongs to it
    # our own earlier output may be replaced; a live run's localisation (--prior-map) only with --overwrite
    own = args.out is None and in_run and not _written_live(run_folder / "alignment.json")
    replaced = check_output_file(out, "--out", (".json",), overwrite=args.overwrite, replaceable=own,
                                 protected_dirs=[archive, prior_archive])
    final = run_folder / "final.tum" if in_run and (run_folder / "final.tum").is_file() else None
    moved = out.parent / "final.prior.tum"
    if final is not None:
        check_output_file(moved, "--out (final.prior.tum beside it)", (".tum",), overwrite=args.overwrite,
                          replaceable=own, inputs=[final], protected_dirs=[archive, prior_archive])
    t0 = time.monotonic()

    def progress(done: int, total: int) -> None:
        if done == total or done % 20 == 0:
            print(f"davio map align: {done}/{total} new views matched ({time.monotonic() - t0:.0f} s)",
                  file=sys.stderr, flush=True)

    res, summary, notes = align_archives(archive, prior_archive, cfg, progress)
    _print_notes("align", notes)
    trajectory = None
    if res.localized and final is not None:
        last = _last_segment(run_folder)
        wrong = last != summary["new_segment"] if last is not None else summary["new_segments"] > 1
        seg_file = run_folder / f"final_segment{summary['new_segment']}.tum"   # written after a reset
        if wrong and seg_file.is_file():
            _print_notes("align", [f"final.prior.tum holds filter segment {summary['new_segment']} "
                                   f"({seg_file.name}), the one aligned; final.tum holds the last ({last})"])
            final, wrong = seg_file, False
        if wrong:
            _print_notes("align", [f"final.tum not moved: it holds the run's last filter segment ({last}), "
                                   f"and segment {summary['new_segment']} of the map was aligned"])
        else:
            trajectory = moved
            summary["final_prior"] = str(trajectory)
            summary["final_prior_source"] = final.name
            summary["final_prior_poses"] = transform_tum(final, trajectory, res.T_PN)
    earlier = _read_json(out) if replaced else None
    try:
        atomic_write_text(out, strict_dumps(summary, indent=1) + "\n")
    except OSError as exc:
        raise ConfigError(f"--out {out}: cannot write ({exc.strerror or exc})") from None
    if trajectory is None and (own or replaced) and moved.is_file():     # the earlier result, now stale
        moved.unlink()
        _print_notes("align", [f"{moved} of an earlier alignment removed: this one moved no trajectory"])
    causal = run_folder / "causal.prior.tum"      # a --prior-map run's poses as published in its prior frame
    earlier = earlier or {}
    was = earlier.get("prior")
    same = (earlier.get("prior_id") == summary["prior_id"] if earlier.get("prior_id") and summary["prior_id"]
            else was == summary["prior"])
    if replaced and in_run and out == run_folder / "alignment.json" and causal.is_file() \
            and not (res.localized and same):
        kept = causal.with_name(EARLIER_PRIOR_CAUSAL)    # published live: it cannot be made again
        causal.replace(kept)
        _print_notes("align", [f"{causal} renamed to {kept.name}: it holds the poses published in the frame "
                               f"of {was or 'the earlier prior map'}, which this alignment replaced"])
    if args.json:
        print(strict_dumps(summary, indent=2))
        return 0 if res.localized else 1
    rej = ", ".join(f"{k} x{v}" for k, v in res.rejected.items() if v) or "none"
    print(f"davio map align: {summary['new_views']} views of {archive} against {summary['prior_views']} of "
          f"{prior_archive}: {res.attempts} candidate pairs, {len(res.hypotheses)} verified (refused: {rej})")
    if res.localized:
        t = res.T_PN[:3, 3]
        views = len({res.hypotheses[i].new for i in res.agreeing})
        print(f"davio map align: localised: yaw {res.yaw_deg:.2f} deg, t = ({t[0]:.3f}, {t[1]:.3f}, "
              f"{t[2]:.3f}) m; {len(res.agreeing)} verified pairs from {views} new views agree (fit: "
              f"{res.fit}, camera centres within {res.centre_rms_m:.3f} m RMS)")
    else:
        print(f"davio map align: not localised: {res.reason}")
    print(f"davio map align: -> {out}{' (replaced)' if replaced else ''}"
          + (f", {trajectory}" if trajectory else ""))
    return 0 if res.localized else 1


def _written_live(path: Path) -> bool:
    """Whether `path` is an alignment.json a run wrote with --prior-map."""
    import json

    from tools.run_prior_frame import LIVE_ALIGNMENT

    try:
        return json.loads(path.read_text()).get("new") == LIVE_ALIGNMENT
    except (OSError, ValueError, AttributeError):
        return False


EARLIER_PRIOR_CAUSAL = "causal.earlier-prior.tum"
"""Where `map align --overwrite` moves a --prior-map run's causal.prior.tum when the new alignment is to
another prior map (or failed): the poses as published live, in the earlier prior's frame."""


def _read_json(path: Path) -> dict | None:
    """The JSON object in `path`, or None when it holds none."""
    import json

    try:
        value = json.loads(path.read_text())
    except (OSError, ValueError, RecursionError):
        return None
    return value if isinstance(value, dict) else None


def _last_segment(run_folder: Path) -> int | None:
    """The filter segment of the run's last published pose (the one final.tum holds), from poses.csv;
    None when it cannot be read."""
    try:
        lines = (run_folder / "poses.csv").read_text().splitlines()
        return int(lines[-1].split(",")[2]) if len(lines) > 1 else None
    except (OSError, ValueError, IndexError):
        return None
