"""A run's outputs in a prior map's frame (`--prior-map`): causal.prior.tum, final.prior.tum,
alignment.json and report.json's "prior_map" (the localisation itself: runtime/graph/prior_frame.py)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from runtime.files import atomic_write_text
from runtime.geometry import PoseTrajectory, make_pose
from runtime.json_out import strict_dumps

LIVE_ALIGNMENT = "this run (live)"
"""alignment.json's "new" when a run wrote it with --prior-map (`davio map align` names the archive)."""


def _own_id(archive: Path) -> str | None:
    """This run's archive id (None when it has no archive, or one that does not read)."""
    from runtime.errors import DataError
    from tools.map_archive.align import archive_id

    try:
        return archive_id(archive) if (archive / "manifest.json").exists() else None
    except DataError:
        return None


SegmentPoses = tuple[int, PoseTrajectory, PoseTrajectory]
"""A filter segment's number and its causal and final map-frame trajectories."""


def write_prior_frame(out_dir: Path, pipeline: Any, segments: list[SegmentPoses],
                      first_t_ns: int | None) -> dict | None:
    """With a prior map: one filter segment's trajectories in its frame (causal.prior.tum: the poses
    published once localised, as published; final.prior.tum: every final pose with the newest transform)
    and alignment.json; returns report.json's "prior_map" (None without a prior map). `segments`: each
    filter segment's (number, causal, final) map-frame trajectories, in order. The segment is the last
    one, or when it was not localised (a reset after the localisation) the latest one that was."""
    from tools.evaluation import write_tum
    from tools.map_alignment_files import relative_prior

    pf = getattr(pipeline, "prior", None)
    if pf is None:
        return None
    localised = [s for s in segments if pf.localizer.T_PN(s[0]) is not None]
    seg, causal, final = (localised or segments or [(0, None, None)])[-1]
    al = pf.localizer.alignment(seg)
    out = {"source": pf.source, "segment": seg,
           **{k: v for k, v in al.as_dict().items() if k != "hypotheses"},
           "localized_after_s": None, "poses_in_prior_frame": 0, "files": [],
           "switches": pf.localizer.switches.get(seg, 0)}
    if causal is None:
        return out
    if segments[-1][0] != seg:
        out["last_segment"] = segments[-1][0]      # not localised: the files hold an earlier segment
    mask, T_PI = pf.causal(seg, causal.t_ns, make_pose(causal.R, causal.p))
    if mask.any():
        write_tum(out_dir / "causal.prior.tum",
                  PoseTrajectory(causal.t_ns[mask], T_PI[:, :3, 3], T_PI[:, :3, :3]))
        out["poses_in_prior_frame"] = int(mask.sum())
        out["files"].append("causal.prior.tum")
        t_loc = pf.localized_at_ns.get(seg)
        if t_loc is not None and first_t_ns is not None:
            out["localized_after_s"] = (t_loc - first_t_ns) * 1e-9
    F = pf.final(seg, make_pose(final.R, final.p))
    if F is not None:
        write_tum(out_dir / "final.prior.tum", PoseTrajectory(final.t_ns, F[:, :3, 3], F[:, :3, :3]))
        out["files"].append("final.prior.tum")
        atomic_write_text(out_dir / "alignment.json", strict_dumps(
            {"format": "davio-alignment", "prior": pf.source,
             "prior_relative": relative_prior(pf.source, out_dir), "new": LIVE_ALIGNMENT, "new_segment": seg,
             "prior_id": getattr(pf.localizer, "prior_id", None), "new_id": _own_id(out_dir / "map"),
             "prior_segment": pf.localizer.prior_segment,
             "frames": "T_PN maps points of this run's map frame into the prior one: x_P = T_PN x_N",
             **al.as_dict(), "switches": out["switches"]}, indent=1) + "\n")
        out["files"].append("alignment.json")
    return out
