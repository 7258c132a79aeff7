"""The console summary of a finished `davio run` / `davio live` (and the demo): the first published state,
the ATE, every recovery the run made (input repairs, rig findings, initializer rejections, resets), the
bring-up, timings, the map and the prior map; one line each."""
from __future__ import annotations

from pathlib import Path

from runtime.rig_findings import rig_lines


def first_published_line(report: dict) -> str:
    """When the first state was published and by whom (and who publishes at the end, when another)."""
    tf = report.get("T_f_s")
    first, now = report.get("first_published_by"), report.get("published_by")
    at_end = "" if first is None or now == first else f" (at the end: {now or 'nobody, after a reset'})"
    return (f"first published state: {'none' if tf is None else f'{tf:.2f} s'} by {first or now or '-'}"
            f"{at_end}; {report['published_poses']} poses")


def summary(report: dict, out: Path) -> None:
    m = report.get("metrics", {})
    print("  " + first_published_line(report))
    if m and "ate_se3_m" not in m and m.get("ate_se3_error"):
        print(f"  ATE: not computed: {m['ate_se3_error']}")
    elif m:
        nan = float("nan")
        print(f"  ATE: {m.get('ate_se3_m', nan):.3f} m (se3), {m.get('ate_posyaw_m', nan):.3f} m (posyaw)"
              + _last_segment_scope(report))
        mc, mf = report.get("metrics_causal") or {}, report.get("metrics_final") or {}
        if report["pipeline"].get("mapping") is not None and mc:
            print(f"  ATE map frame: causal {mc.get('ate_se3_m', nan):.3f} m, "
                  f"final {mf.get('ate_se3_m', nan):.3f} m (se3)")
    by_segment = segments_line(report)
    if by_segment:
        print(f"  {by_segment}")
    for line in recovery_lines(report):
        print(f"  {line}")
    bu = report["pipeline"].get("bringup")
    if bu is not None:
        state = "done" if bu["R_IC"] else "NOT done"
        rms = bu["fit_rms_deg"] or float("nan")
        source = "DA3" if bu.get("rotation_source", "model") == "model" else "two-view fits of the tracks"
        print(f"  hand-eye bring-up: {state} after {bu['windows_used']} windows, rotations from {source} "
              f"(fit RMS {rms:.2f} deg, rejections {bu['rejections'] or '{}'})")
    s = report["scheduler"]
    print(f"  tracking {s.get('tracking_ms_per_frame_median', float('nan')):.1f} ms/frame (median), "
          f"real-time factor {s.get('realtime_factor') or float('nan'):.2f}")
    mp = report["pipeline"].get("mapping")
    if mp is not None:
        print("  " + mapping_line(mp, report.get("map") or {}, report.get("config", {}).get("mapping")))
    if report.get("prior_map") is not None:
        print("  " + prior_line(report["prior_map"]))
    st = report.get("stream")
    if st is not None:
        print(f"  stream: {st['poses_sent']} poses and {st['events_sent']} events sent to {st['url']}"
              + (f"; {st['not_sent']} not sent (first: {st['first_error']})" if st["not_sent"] else ""))
    print(f"  outputs: {out}/odometry.tum, causal.tum, final.tum, poses.csv, report.json, config.toml"
          + (", events.jsonl" if (Path(out) / "events.jsonl").is_file() else "")
          + (", plots" if m else "")
          + (", map/, map.ply" if (report.get("map") or {}).get("ply") else ""))


def prior_line(pm: dict) -> str:
    """One console line: localised in the prior map or not, and why."""
    if pm["localized"]:
        t = pm["t"]
        after = pm["localized_after_s"]
        return (f"prior map: localised {'' if after is None else f'{after:.1f} s into the run '}(yaw "
                f"{pm['yaw_deg']:.2f} deg, t = ({t[0]:.3f}, {t[1]:.3f}, {t[2]:.3f}) m; {pm['agreeing']} "
                f"verified pairs agree); {pm['poses_in_prior_frame']} poses published in its frame -> "
                "causal.prior.tum, final.prior.tum"
                + (f"; a wrong lock was replaced {pm['switches']}x (a look-alike place outvoted; "
                   "causal.prior.tum holds the poses published before)" if pm.get("switches") else "")
                + (f"; these files and alignment.json hold filter segment {pm['segment']}, the last one "
                   f"localised: segment {pm['last_segment']}, after a reset, was not"
                   if pm.get("last_segment") is not None else ""))
    return (f"prior map: NOT localised ({pm['reason']}; {pm['attempts']} candidate pairs tried, "
            f"{pm['verified']} verified)")


def _last_segment_scope(report: dict) -> str:
    """After filter resets: what the ATE covers (the last segment)."""
    segments = report.get("segments") or []
    if len(segments) < 2:
        return ""
    return (f" over the last segment only ({segments[-1]['poses']} of {report['published_poses']} poses: "
            f"the filter was reset {len(segments) - 1}x, each segment in its own frame)")


def segments_line(report: dict) -> str:
    """After filter resets, when ground truth scored any segment: every segment's ATE ('' otherwise)."""
    segments = report.get("segments") or []
    scored = [s for s in segments if "ate_se3_m" in (s.get("metrics") or {})]
    if len(segments) < 2 or not scored:
        return ""
    each = ", ".join(f"{s['metrics']['ate_se3_m']:.3f} m ({s['poses']} poses)" if s in scored
                     else f"- ({s['poses']} poses)" for s in segments)
    return (f"ATE by segment (se3): {each}; their trajectories: odometry_segment<k>.tum, "
            f"causal_segment<k>.tum, final_segment<k>.tum")


def mapping_line(mp: dict, summary: dict, config: dict | None = None) -> str:
    """One console line: windows mapped / offered, drops, rejections by reason, retained points, the
    voxels in map.ply or why there is none (`config`: report.json's config "mapping")."""
    rej = ", ".join(f"{k} x{v}" for k, v in sorted(mp["windows_rejected"].items())) or "none"
    sampled = max(mp["points_sampled"], 1)
    invalid = 100 * mp.get("rejected_invalid_depth", 0) / sampled
    return (f"map: {mp['windows_accepted']}/{mp['windows_offered']} windows mapped, "
            f"{mp['windows_dropped_queue']} dropped (queue full), rejected: {rej}; "
            f"{mp['points_retained']} points kept ({invalid:.0f} % invalid depth, "
            f"{100 * mp['rejected_confidence'] / sampled:.0f} % low "
            f"confidence, {100 * mp['rejected_multiview'] / sampled:.0f} % failed the multi-view test, "
            f"{100 * mp.get('points_unverified', 0) / sampled:.0f} % kept seen by one image only); "
            + _ply_text(mp, summary, config) + _graph_text(mp.get("graph"))
            + _archive_stopped_text(summary.get("archive_stopped"), bool(summary.get("ply"))))


def invalid_depth_line(mp: dict, config: dict) -> str:
    """A warning when the model's depths were mostly outside the mapped range: depth in other units, inverse
    or negative (a user's export), or a scene beyond mapping.max_depth_m; "" otherwise."""
    sampled, invalid = mp.get("points_sampled", 0), mp.get("rejected_invalid_depth", 0)
    refused = (mp.get("windows_rejected") or {}).get("invalid_depth", 0)
    processed = mp.get("windows_processed") or refused
    if not (sampled and invalid > 0.5 * sampled) and not (refused and refused > 0.5 * processed):
        return ""     # a window down a long hall now and then is the scene, not the model
    far = config.get("max_depth_m", 20.0)
    return (f"MODEL DEPTH? {100 * invalid / max(sampled, 1):.0f} % of the depths the model returned were not "
            f"in (0, {far:g} m] ({refused} windows refused as invalid_depth): is the graph's depth in metres "
            "(not mm, not inverse depth), or is the scene beyond mapping.max_depth_m?")


def _ply_text(mp: dict, summary: dict, config: dict | None) -> str:
    if summary.get("ply") and summary.get("ply_segment") is not None:
        sizes = summary.get("segment_submaps") or {}
        return (f"{summary.get('voxels', 0)} voxels in {summary['ply']}, of filter segment "
                f"{summary['ply_segment']} ({sizes.get(str(summary['ply_segment']), '?')} of "
                f"{sum(sizes.values())} submaps; its trajectory: final_segment{summary['ply_segment']}.tum): "
                f"the filter was reset, and each segment's map has its own frame; `davio map export RUN "
                f"--segment K --out FILE.ply` writes another")
    if summary.get("ply"):
        return f"{summary.get('voxels', 0)} voxels in {summary['ply']}"
    if summary.get("export_error"):
        return f"no map.ply: the export failed ({summary['export_error']}); `davio map export RUN` retries it"
    if summary.get("archive_stopped"):
        return "no map.ply (the archive stopped before its first commit)"
    if mp["windows_offered"] or not config:
        return "no map.ply (nothing was mapped)"
    n, dt = config["window_images"], config["keyframe_spacing_s"]
    return (f"no map.ply: no window was complete (a window is {n} keyframes {dt:g} s apart taken while poses "
            f"are published, {(n - 1) * dt:g} s; run longer)")


def _archive_stopped_text(stopped: dict | None, ply: bool = True) -> str:
    if not stopped:
        return ""
    free = "" if stopped.get("free_mb") is None else f": {stopped['free_mb']:g} MB"
    return (f"\n  WARNING: the map archive stopped at map version {stopped['map_version']} "
            f"({stopped['reason']}{free}); {stopped['commits_skipped']} later commits were not archived"
            + (", and map.ply holds the map up to then" if ply else ""))


def _graph_text(g: dict | None) -> str:
    if not g:
        return ""
    rv = g.get("revisits") or {}
    rej = ", ".join(f"{k} x{v}" for k, v in sorted((rv.get("rejected") or {}).items()) if v) or "none"
    return (f"; graph: {g['solves']} solves ({g['solve_s_max']:.2f} s max), revisits {rv.get('accepted', 0)}"
            f"/{rv.get('attempts', 0)} verified (refused: {rej}), {rv.get('point_groups', 0)} past the "
            "drift gate")


_DRIVER_COUNTERS = {
    "truncated_lines": "truncated lines", "malformed_lines": "malformed lines",
    "dropped_nonfinite": "non-finite samples dropped", "dropped_nonmonotonic": "corrupt stamps dropped",
    "dropped_duplicate": "duplicates dropped", "reordered": "out-of-order rows sorted",
    "converted": "converted", "missing_images": "missing images", "repeated_images": "repeated images",
    "unreadable_images": "unreadable images", "late_images": "images recorded too late", "gaps": "gaps",
}


ESTIMATED_OFFSET_NOTE_S = 0.005
"""The console names the filter's estimate of the camera-IMU time offset when it ends at least this far (s),
and three of its standard deviations, from the offset in use (the rig's, or the one the start-up adopted):
about a sample period of a 200 Hz IMU, and five times the estimate's spread on a right rig (BENCHMARKS
"The camera-IMU time offset in the filter's state")."""


SETTLED_OFFSET_STD_S = 0.0005
"""An estimate of the time offset whose standard deviation is larger is not offered as the rig's: on a
helper's 40 simulated runs the estimates that settled (true offsets 0 and +50 ms) ended with a std of
0.1-0.4 ms, and the five that ended 11-17 ms from a true 0 (a rotation 10-15 deg off, a slow start) with
1.0-2.7 ms."""


def _estimated_offset_line(filter_rep: dict, startup: dict, rig_offset_s: float | None) -> str | None:
    """The console's word on the publishing filter's estimate of the camera-IMU time offset (msckf.
    calib_time_offset) when it ends far from the offset in use; None otherwise."""
    est, std = filter_rep.get("time_offset_s"), filter_rep.get("time_offset_std_s")
    if not filter_rep.get("time_offset_estimated") or est is None or std is None:
        return None
    rig = rig_offset_s or 0.0
    adopted = startup.get("time_offset_adopted_s")
    ref = rig if adopted is None else adopted
    if abs(est - ref) < max(ESTIMATED_OFFSET_NOTE_S, 3.0 * std):
        return None
    said = f"the rig says {rig * 1e3:+.1f} ms" + ("" if adopted is None else
                                                  f", the start-up adopted {adopted * 1e3:+.1f} ms")
    if std > SETTLED_OFFSET_STD_S:
        return (f"CAMERA-IMU TIME OFFSET? the filter's estimate ended at {est * 1e3:+.1f} +- "
                f"{std * 1e3:.1f} ms ({said}), not settled enough to copy into a rig file: an estimate this "
                "uncertain can absorb another error (a camera-IMU rotation a few degrees off, a slow or weak "
                "start)")
    return (f"CAMERA-IMU TIME OFFSET: the filter estimated {est * 1e3:+.1f} +- {std * 1e3:.1f} ms at the end "
            f"({said}; t_imu = t_cam + offset). If the rig file is yours, put the estimate in it "
            "(Kalibr timeshift_cam_imu)")


def input_lines(driver_report: dict | None) -> list[str]:
    """One console line per input stream the driver repaired (its counters), then its notes."""
    lines = []
    for name, counts in ((driver_report or {}).get("streams") or {}).items():
        parts = [f"{label} {counts[k]}" for k, label in _DRIVER_COUNTERS.items() if counts.get(k)]
        if parts:
            lines.append(f"input {name}: " + ", ".join(parts))
    lines.extend(f"input note: {n}" for n in (driver_report or {}).get("notes") or [])
    return lines


LATE_START_S = 5.0
"""A first pose later than this (data seconds) is a late start, and the console says what the native
initializers refused before it (the feed-forward start-up publishes in about 1.4 s, the native initializers
from a standstill in about 2 s)."""


def late_start_line(report: dict) -> str:
    """Why the first pose came late: each native initializer's refusals before it; "" when it did not."""
    from tools.run_outcome import _rejections

    tf = report.get("T_f_s")
    if tf is None or tf <= LATE_START_S:
        return ""
    # as they stood at the first pose (the filter publishing at the end may have refused more since)
    inits = ((report.get("pipeline") or {}).get("startup") or {}).get("refused_before_first") or {}
    why = "; ".join(f"{name}: {_rejections(r)}" for name, r in inits.items() if r.get("rejections"))
    return (f"LATE START: the first pose came {tf:.1f} s into the data"
            + (f"; before it the native initializers refused: {why}" if why else ""))


def recovery_lines(report: dict) -> list[str]:
    """One console line per kind of recovery the run made (input repairs, initializer rejections,
    filter resets), so that nothing counted in report.json goes unnoticed on the console."""
    lines = input_lines(report.get("driver"))
    late = late_start_line(report)
    if late:
        lines.append(late)
    out_of_range = (report["pipeline"].get("tracking") or {}).get("imu_out_of_range") or 0
    if out_of_range:
        from runtime.pipeline import MAX_ACCEL_M_S2, MAX_GYRO_RAD_S

        lines.append(f"IMU samples beyond any IMU's range dropped: {out_of_range} (|gyro| > "
                     f"{MAX_GYRO_RAD_S:g} rad/s or |accel| > {MAX_ACCEL_M_S2:g} m/s^2 on an axis: corrupt "
                     "values, or a gyroscope in deg/s?)")
    from runtime.imu.rate_quantiles import GYRO_UNITS_P90_RAD_S

    p90 = (report["pipeline"].get("tracking") or {}).get("gyro_rate_p90_rad_s")
    if p90 is not None and p90 > GYRO_UNITS_P90_RAD_S:
        lines.append(f"GYROSCOPE UNITS? a tenth of the run turns faster than {p90:.1f} rad/s (EuRoC's "
                     "flights: 0.6-1.0 rad/s); a gyroscope logging deg/s reads 57.3 times too high: check "
                     "its unit (rad/s)")
    tracking = report["pipeline"].get("tracking") or {}
    errors = tracking.get("ff_exceptions") or []
    if errors:
        lines.append(f"feed-forward model calls failed: {max(tracking.get('ff_errors') or 0, len(errors))} "
                     f"(first: {errors[0]})")
    mapping = report["pipeline"].get("mapping") or {}
    map_errors = mapping.get("model_errors") or []
    failed = sum((mapping.get("windows_rejected") or {}).get(k, 0) for k in ("model_error", "exception"))
    if map_errors or failed:
        first = f" (first: {map_errors[0]})" if map_errors else ""
        lines.append(f"mapping model calls failed: {max(failed, len(map_errors))}{first}")
    line = invalid_depth_line(mapping, (report.get("config") or {}).get("mapping") or {})
    if line:
        lines.append(line)
    startup = report["pipeline"].get("startup") or {}
    if startup.get("ff_rejections"):
        reasons = ", ".join(f"{k} x{v}" for k, v in sorted(startup["ff_rejections"].items()))
        lines.append(f"feed-forward windows rejected: {reasons}")
    rig_offset_s = (report.get("rig") or {}).get("time_offset_s")
    lines.extend(rig_lines(report["pipeline"], rig_offset_s))
    line = _estimated_offset_line(report["pipeline"].get("filter") or {}, startup, rig_offset_s)
    if line:
        lines.append(line)
    if startup.get("ff_extensions"):
        ext_rej = startup.get("ff_extension_rejections") or {}
        reasons = ", ".join(f"{k} x{v}" for k, v in sorted(ext_rej.items()))
        lines.append(f"refused windows re-solved over a longer span: {startup['ff_extensions']}, "
                     f"{startup.get('ff_extension_accepted', 0)} accepted"
                     + (f" (rejected: {reasons})" if reasons else ""))
    # every diverged filter sends start-up back to both initializers (the filter counters only know their own)
    resets = startup.get("restarts_after_divergence") or 0
    if resets:
        segments = len(report.get("segments") or [])
        lines.append(f"filter resets after divergence: {resets} ({segments} segments)")
    return lines
