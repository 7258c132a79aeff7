"""`davio eval ate|rpe|surface`: trajectory and map accuracy with evo-compatible definitions."""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from runtime.errors import ConfigError
from runtime.json_out import strict_dumps
from tools.cli_types import count, number

NAME = "eval"
HELP = "evaluate a trajectory (ATE, RPE; TUM or EuRoC CSV) or a point cloud (surface metrics)"
DESCRIPTION = (
    "Evaluate accuracy. 'ate' and 'rpe' read TUM (t[s] x y z qx qy qz qw) or EuRoC state CSV files, "
    "associate stamps (nearest within --max-diff seconds) and align the estimate (se3, sim3, posyaw = "
    "translation + yaw about gravity, none); numbers match evo_ape / evo_rpe on the same files. "
    "'surface' compares a reconstructed cloud with a reference cloud (accuracy, completeness, F-score)."
)


def _add_common(p: argparse.ArgumentParser) -> None:
    p.add_argument("est", metavar="EST", help="estimated trajectory (TUM or EuRoC CSV)")
    p.add_argument("ref", metavar="REF", help="reference trajectory (TUM or EuRoC CSV)")
    p.add_argument("--max-diff", type=number, default=0.01, metavar="S",
                   help="largest stamp difference for association, seconds")
    p.add_argument("--offset", type=number, default=0.0, metavar="S",
                   help="time offset added to the estimate's stamps for association, seconds")
    p.add_argument("--one-to-one", action="store_true",
                   help="use each pose in at most one pair (evo may reuse a pose for repeated stamps)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.add_argument("--plot", metavar="DIR", default=None, help="write PNG plots into this folder")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from tools.evaluation.align import METHODS

    sub = parser.add_subparsers(dest="eval_command", metavar="{ate,rpe,surface}")
    fmt = argparse.ArgumentDefaultsHelpFormatter
    p = sub.add_parser("ate", help="absolute trajectory error", formatter_class=fmt)
    _add_common(p)
    p.add_argument("--align", choices=METHODS, default="se3", help="alignment of the estimate")
    p.add_argument("--n-align", type=count(2), default=None, metavar="N",
                   help="fit the alignment on the first N associated poses only")
    p.add_argument("--save-aligned", metavar="FILE", default=None,
                   help="write the associated, aligned estimate as a TUM file (an existing folder: "
                        "EST_aligned.tum inside it; .tum or .txt)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --save-aligned file")
    p.set_defaults(_eval=_run_ate)

    p = sub.add_parser("rpe", help="relative pose error", formatter_class=fmt)
    _add_common(p)
    p.add_argument("--delta", type=number, default=1.0, help="pair spacing")
    p.add_argument("--delta-unit", choices=("f", "m"), default="f", help="frames or metres of path")
    p.add_argument("--all-pairs", action="store_true", help="start a pair at every pose")
    p.add_argument("--align", choices=METHODS, default="none", help="alignment before (sim3 fixes scale)")
    p.set_defaults(_eval=_run_rpe)

    p = sub.add_parser("surface", help="surface metrics of a point cloud", formatter_class=fmt)
    p.add_argument("rec", metavar="REC", help="reconstructed cloud (.ply, .pcd, .xyz, .npy)")
    p.add_argument("ref", metavar="REF", help="reference cloud (.ply, .pcd, .xyz, .npy)")
    p.add_argument("--threshold", type=number, default=0.1, metavar="M", help="match distance, metres")
    p.add_argument("--voxel", type=number, default=None, metavar="M",
                   help="voxel-downsample both clouds first (side in metres)")
    p.add_argument("--align-with", nargs=2, metavar=("EST", "REF"), default=None,
                   help="move REC by the alignment of trajectory EST (in REC's frame, e.g. the run's "
                        "final.tum) to trajectory REF (in the reference cloud's frame, e.g. groundtruth.tum) "
                        "first; without it both clouds must already share a frame")
    p.add_argument("--align", choices=METHODS, default="se3",
                   help="with --align-with: the trajectory alignment (se3: rigid, as the paper; no ICP)")
    p.add_argument("--max-diff", type=number, default=0.01, metavar="S",
                   help="with --align-with: association window of the two trajectories (s)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.set_defaults(_eval=_run_surface)


def _stats_table(title: str, rows: list[tuple[str, dict, str]], extra: list[tuple[str, str]]):
    from rich.table import Table

    table = Table(title=title)
    table.add_column("statistic")
    for name, _, unit in rows:
        table.add_column(f"{name} ({unit})", justify="right")
    for key in ("rmse", "mean", "median", "std", "min", "max"):
        table.add_row(key, *[f"{stats[key]:.6f}" for _, stats, _ in rows])
    info = Table(show_header=False, box=None)
    for k, v in extra:
        info.add_row(k, v)
    return table, info


def _print(*renderables) -> None:
    from tools.stdout_console import stdout_console

    con = stdout_console()
    for r in renderables:
        con.print(r)


def _read_pair(est: str, ref: str) -> tuple:
    """(estimate, reference) trajectories; a note on stderr for each file read with ns stamps, and for each
    file with repeated stamps (kept, as evo keeps them: a repeated pose may go unpaired, or share its
    partner, which changes the pair count and the statistics)."""
    from tools.evaluation import read_trajectory

    trajs = read_trajectory(est), read_trajectory(ref)
    for t in trajs:
        if "stamp_note" in t.meta:
            print(f"davio eval: note: {t.meta['stamp_note']}", file=sys.stderr)
        repeats = int(t.meta.get("repeated_stamps") or 0)
        if repeats:
            poses = "1 pose repeats" if repeats == 1 else f"{repeats} poses repeat"
            print(f"davio eval: note: {t.meta['source']}: {poses} the stamp before (kept, as evo keeps "
                  "them; the association pairs each stamp of the shorter trajectory once, so a repeated pose "
                  "may go unpaired or share its partner)", file=sys.stderr)
    return trajs


def check_map_segment(rec: Path, est: Path) -> None:
    """ConfigError when REC is a run's map.ply and EST a trajectory of that run from another filter segment:
    after a reset map.ply holds the segment with the most placeable submaps, each segment in its own map
    frame, while final.tum and causal.tum hold the last segment."""
    import json
    import re

    from tools.evaluation.ply import ply_comments

    folder = rec.parent
    m = re.fullmatch(r"(final|causal)(?:_segment(\d+))?\.tum", est.name)
    if rec.suffix != ".ply" or m is None or est.parent.resolve() != folder.resolve():
        return
    said = [c.split()[1] for c in ply_comments(rec) if len(c.split()) == 2 and c.split()[0] == "segment"]
    try:      # the segment the PLY says it holds (`davio map export --segment K` may have rewritten it)
        report_file = folder / "report.json"
        report = json.loads(report_file.read_text())
        n = len(report["segments"])
        ply_segment = int(said[0]) if said else None
        as_written = rec.name == "map.ply" and rec.stat().st_mtime <= report_file.stat().st_mtime
        if ply_segment is None and as_written:      # an older davio's map.ply, as its run wrote it
            ply_segment = (report.get("map") or {}).get("ply_segment")
    except (OSError, ValueError, KeyError, TypeError, AttributeError):   # not a run folder
        return
    segment = int(m.group(2)) if m.group(2) is not None else n - 1
    if n > 1 and isinstance(ply_segment, int) and segment != ply_segment:
        raise ConfigError(f"{rec} holds filter segment {ply_segment} of the run, {est.name} segment "
                          f"{segment}: the filter was reset {n - 1}x and each segment's map has its own "
                          f"frame; align with {folder / f'final_segment{ply_segment}.tum'}")


def _repeats(est, ref) -> dict:
    """The report's count of repeated stamps in each input file."""
    return {"repeated_stamps": {"est": int(est.meta.get("repeated_stamps") or 0),
                                "ref": int(ref.meta.get("repeated_stamps") or 0)}}


def _plot_dir(args: argparse.Namespace) -> Path | None:
    """The --plot folder, checked before the evaluation and made only when the plots are written (a failed
    evaluation leaves no empty folder); ConfigError when it names an existing file or cannot be made or
    written."""
    if not args.plot:
        return None
    from tools.output_file import check_folder_can_be_made

    d = Path(args.plot)
    if d.exists() and not d.is_dir():
        raise ConfigError(f"--plot {d}: is a file; --plot takes a folder for the PNG plots")
    check_folder_can_be_made(d, "--plot")   # probed: root passes os.access on /proc
    return d


def _make_plot_dir(d: Path) -> Path:
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"--plot {d}: cannot create the folder ({exc.strerror or exc})") from None
    return d


_FINITE = {"max_diff": (0.0, 9.2e9), "offset": (-9.2e9, 9.2e9), "delta": (0.0, None),
           "threshold": (1e-6, 100.0), "voxel": (1e-4, 100.0)}
"""Numeric options checked before any file is read: (exclusive lower bound, upper bound) in their units, or
[lower, upper] when an upper bound is given (seconds: what int64 nanoseconds hold)."""


def check_numbers(args: argparse.Namespace) -> None:
    """ConfigError naming the option for a non-finite or out-of-range number (NaN would pass every
    comparison further down)."""
    for name, (lo, hi) in _FINITE.items():
        v = getattr(args, name, None)
        if v is None:
            continue
        flag = "--" + name.replace("_", "-")
        if not math.isfinite(v) or (hi is None and not v > lo) or (hi is not None and not lo <= v <= hi):
            rng = f"> {lo:g}" if hi is None else f"in [{lo:g}, {hi:g}]"
            raise ConfigError(f"{flag} must be a finite number {rng}, got {v}")


def aligned_path(save: str, est: str) -> Path:
    """Where --save-aligned writes: the path itself, or `<EST stem>_aligned.tum` inside an existing folder."""
    p = Path(save)
    return p / f"{Path(est).stem}_aligned.tum" if p.is_dir() else p


def _run_ate(args: argparse.Namespace) -> int:
    from tools.evaluation import ate, write_tum

    plot_dir = _plot_dir(args)
    target = None
    if args.save_aligned:
        from tools.output_file import check_output_file

        target = aligned_path(args.save_aligned, args.est)
        check_output_file(target, "--save-aligned", (".tum", ".txt"), overwrite=args.overwrite,
                          inputs=[Path(args.est), Path(args.ref)])
    est, ref = _read_pair(args.est, args.ref)
    res = ate(est, ref, args.align, args.max_diff, args.offset, args.n_align, args.one_to_one)
    out = {**res.as_dict(), "est": str(args.est), "ref": str(args.ref), **_repeats(est, ref)}
    if args.n_align is not None:
        out["n_align"] = min(int(args.n_align), len(res.t_ns))
        if args.n_align > len(res.t_ns):
            print(f"davio eval: note: --n-align {args.n_align} exceeds the {len(res.t_ns)} associated pairs: "
                  "the alignment used all of them", file=sys.stderr)
    if plot_dir is not None:
        from tools.evaluation.plots import plot_errors, plot_trajectories

        d = _make_plot_dir(plot_dir)
        out["plots"] = [str(plot_trajectories(d / "ate_trajectories.png", res.ref, res.est_aligned,
                                              f"ATE, {args.align} alignment")),
                        str(plot_errors(d / "ate_errors.png", res.t_ns, res.trans_err_m, "m",
                                        f"ATE translation, rmse {res.rmse:.4f} m"))]
    if target is not None:
        try:
            write_tum(target, res.est_aligned)
        except OSError as exc:
            raise ConfigError(f"--save-aligned {target}: cannot write ({exc.strerror or exc})") from None
        out["aligned"] = str(target)
    if args.json:
        print(strict_dumps(out))
        return 0
    al = res.alignment
    table, info = _stats_table(f"ATE of {Path(args.est).name} vs {Path(args.ref).name}",
                               [("translation", res.trans, "m"), ("rotation", res.rot, "deg")],
                               [("alignment", f"{al.method} (scale {al.s:.6f}, yaw "
                                              f"{al.as_dict()['yaw_deg']:.3f} deg)"),
                                ("pairs", f"{out['pairs']} of {res.n_est} estimate / {res.n_ref} reference "
                                          f"poses (max diff {args.max_diff} s)"),
                                ("reference path", f"{out['path_length_ref_m']:.3f} m")]
                               + [("plot", p) for p in out.get("plots", [])]
                               + [("aligned estimate", out[k]) for k in ("aligned",) if k in out])
    _print(table, info)
    return 0


def _run_rpe(args: argparse.Namespace) -> int:
    from tools.evaluation import rpe

    plot_dir = _plot_dir(args)
    est, ref = _read_pair(args.est, args.ref)
    res = rpe(est, ref, args.delta, args.delta_unit, args.all_pairs, align_method=args.align,
              max_diff_s=args.max_diff, offset_s=args.offset, one_to_one=args.one_to_one)
    out = {**res.as_dict(), "est": str(args.est), "ref": str(args.ref), **_repeats(est, ref)}
    if plot_dir is not None:
        from tools.evaluation.plots import plot_errors

        png = _make_plot_dir(plot_dir) / "rpe_errors.png"
        out["plots"] = [str(plot_errors(png, res.t_ns, res.trans_err_m, "m",
                                        f"RPE translation, delta {args.delta} {args.delta_unit}"))]
    if args.json:
        print(strict_dumps(out))
        return 0
    unit = "frames" if args.delta_unit == "f" else "m"
    table, info = _stats_table(f"RPE of {Path(args.est).name} vs {Path(args.ref).name}",
                               [("translation", res.trans, "m"), ("rotation", res.rot, "deg")],
                               [("delta", f"{args.delta:g} {unit}, "
                                          f"{'all' if args.all_pairs else 'consecutive'} pairs"),
                                ("pairs", str(out["pairs"])), ("alignment", args.align)]
                               + [("plot", p) for p in out.get("plots", [])])
    _print(table, info)
    return 0


def _run_surface(args: argparse.Namespace) -> int:
    import numpy as np
    from rich.table import Table

    from tools.evaluation import read_point_cloud, surface_metrics

    if args.align_with:
        check_map_segment(Path(args.rec), Path(args.align_with[0]))
    rec = read_point_cloud(args.rec)
    alignment = None
    if args.align_with:
        from tools.evaluation import ate

        est_traj, ref_traj = _read_pair(*args.align_with)
        alignment = ate(est_traj, ref_traj, args.align, args.max_diff).alignment
        rec = alignment.s * np.asarray(rec, np.float64) @ alignment.R.T + alignment.t
    ref = read_point_cloud(args.ref)
    nonfinite = {}
    for name, path, pts in (("rec", args.rec, rec), ("ref", args.ref, ref)):
        arr = np.asarray(pts, np.float64).reshape(-1, 3)
        nonfinite[name] = int((~np.isfinite(arr).all(axis=1)).sum())
        if nonfinite[name]:
            print(f"davio eval: note: {path}: {nonfinite[name]} of {len(arr)} points are not finite (NaN or "
                  "Inf) and are left out", file=sys.stderr)
    res = surface_metrics(rec, ref, args.threshold, args.voxel)
    out = {**res.as_dict(), "rec": str(args.rec), "ref": str(args.ref), "nonfinite_points": nonfinite,
           "alignment": None if alignment is None else alignment.as_dict(),
           **(_repeats(est_traj, ref_traj) if alignment is not None else {})}
    if args.json:
        print(strict_dumps(out))
        return 0
    t = Table(title=f"surface metrics of {Path(args.rec).name} vs {Path(args.ref).name}", show_header=False)
    t.add_row("accuracy (rec -> ref, mean / median)", f"{res.accuracy_m:.4f} / {res.accuracy_median_m:.4f} m")
    t.add_row("completeness (ref -> rec, mean / median)",
              f"{res.completeness_m:.4f} / {res.completeness_median_m:.4f} m")
    t.add_row("chamfer (mean of both)", f"{res.chamfer_m:.4f} m")
    t.add_row(f"precision / recall @ {res.threshold_m:g} m", f"{res.precision:.4f} / {res.recall:.4f}")
    t.add_row("F-score", f"{res.fscore:.4f}")
    t.add_row("points (rec / ref)", f"{res.n_rec} / {res.n_ref}")
    if alignment is not None:
        t.add_row("REC moved by", f"{alignment.method} alignment of {Path(args.align_with[0]).name} to "
                                  f"{Path(args.align_with[1]).name}")
    _print(t)
    return 0


def run(args: argparse.Namespace) -> int:
    if not getattr(args, "_eval", None):
        print("davio eval: name an evaluation: ate, rpe or surface (see davio eval --help)")
        return 2
    check_numbers(args)
    return int(args._eval(args) or 0)
