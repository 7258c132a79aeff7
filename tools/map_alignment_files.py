"""A run folder's alignment.json: written by `davio map align RUN --to PRIOR` (with final.prior.tum, the
run's final trajectory in the prior frame), read by `davio map export --in-prior/--merge-prior`. A run made
with `--prior-map` writes one live (tools/run_prior_frame.py)."""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from runtime.errors import ConfigError, DataError
from runtime.json_out import strict_dumps


def _print_notes(lines: list[str]) -> None:
    for line in lines:
        print(f"davio map align: note: {line}", file=sys.stderr)


def read_alignment(run_folder: Path, merge: bool, archive: Path | None = None) -> tuple:
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
    prior = _find_prior(path, al, prior)
    _check_aligned_maps(path, al, archive if archive is not None else run_folder / "map", prior)
    if merge and not (prior / "manifest.json").is_file():
        raise ConfigError(f"{path} names the prior map {prior}, which is gone (no manifest.json there): if "
                          "it was moved, align the run to it again (`davio map align RUN --to PRIOR "
                          "--overwrite`)")
    return T, prior, *segments


def relative_prior(prior: str | Path, alignment_folder: Path) -> str | None:
    """alignment.json's "prior_relative": the prior archive's path from the alignment's folder, so that a
    pair of runs moved or copied together (another disk, another machine) still finds it; None when no
    relative path exists (another drive)."""
    try:
        return os.path.relpath(Path(prior).resolve(), Path(alignment_folder).resolve())
    except ValueError:
        return None


def _find_prior(path: Path, al: dict, prior: Path) -> Path:
    """The prior archive: at the path recorded, or where the recorded relative path leads when the runs
    were moved together (a note says so); the one whose archive id is the recorded one when both exist."""
    rel = al.get("prior_relative")
    moved = (path.parent / rel) if isinstance(rel, str) and rel else None
    if moved is None or not (moved / "manifest.json").is_file() or moved.resolve() == prior.resolve():
        return prior
    want = al.get("prior_id") if isinstance(al.get("prior_id"), str) else None
    if (prior / "manifest.json").is_file() and want in (None, _archive_id(prior)):
        return prior
    if want is not None and _archive_id(moved) != want:
        return prior           # not the aligned map either: the id check says so
    where = ("holds another map (replaced since)" if (prior / "manifest.json").is_file()
             else "is gone (the runs were moved?)")
    print(f"davio map: note: {prior} {where}: using {moved.resolve()}, where {path.name} leads relative to "
          "its folder", file=sys.stderr)
    return moved.resolve()


def _archive_id(folder: Path) -> str | None:
    from tools.map_archive.align import archive_id

    try:
        return archive_id(folder) if (folder / "manifest.json").is_file() else None
    except DataError:          # a damaged archive: the export itself says what is wrong with it
        return None


def _check_aligned_maps(path: Path, al: dict, own: Path, prior: Path) -> None:
    """ConfigError when the maps are not the ones aligned: the prior was replaced at its path since, or the
    alignment was written for another run's map (`davio map align X --out THIS_RUN`). An alignment of an
    older davio records no ids: taken as it is, unless the map now has one (ids are written since; a map with
    one was written after the alignment: replaced)."""
    if not isinstance(al.get("prior_id"), str) and _archive_id(prior) is not None:
        raise ConfigError(f"{prior} is not the map this run was aligned to (it was replaced since: it has an "
                          f"archive id, written after {path.name}, which records none): align the run again")
    if isinstance(al.get("new_id"), str) and _archive_id(own) not in (None, al["new_id"]):
        raise ConfigError(f"{path} aligns another map ({al.get('new')}), not this run's: align this run "
                          f"(`davio map align {own.parent} --to PRIOR`)")
    if isinstance(al.get("prior_id"), str) and _archive_id(prior) not in (None, al["prior_id"]):
        raise ConfigError(f"{prior} is not the map this run was aligned to (it was replaced since: its "
                          f"archive id differs): align the run again")


def align(args: argparse.Namespace, archive: Path, run_folder: Path) -> int:
    from runtime.files import atomic_write_text
    from runtime.graph.relocalize import AlignConfig
    from tools.commands.map import output_path, resolve
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
    summary["prior_relative"] = relative_prior(prior_archive, out.parent)
    _print_notes(notes)
    trajectory = None
    if res.localized and final is not None:
        last = _last_segment(run_folder)
        wrong = last != summary["new_segment"] if last is not None else summary["new_segments"] > 1
        seg_file = run_folder / f"final_segment{summary['new_segment']}.tum"   # written after a reset
        if wrong and seg_file.is_file():
            _print_notes([f"final.prior.tum holds filter segment {summary['new_segment']} "
                                   f"({seg_file.name}), the one aligned; final.tum holds the last ({last})"])
            final, wrong = seg_file, False
        if wrong:
            _print_notes([f"final.tum not moved: it holds the run's last filter segment ({last}), "
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
        _print_notes([f"{moved} of an earlier alignment removed: this one moved no trajectory"])
    causal = run_folder / "causal.prior.tum"      # a --prior-map run's poses as published in its prior frame
    earlier = earlier or {}
    was = earlier.get("prior")
    same = (earlier.get("prior_id") == summary["prior_id"] if earlier.get("prior_id") and summary["prior_id"]
            else was == summary["prior"])
    if replaced and in_run and out == run_folder / "alignment.json" and causal.is_file() \
            and not (res.localized and same):
        kept = causal.with_name(EARLIER_PRIOR_CAUSAL)    # published live: it cannot be made again
        causal.replace(kept)
        _print_notes([f"{causal} renamed to {kept.name}: it holds the poses published in the frame "
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
