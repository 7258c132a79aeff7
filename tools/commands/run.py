"""`davio run PATH`: run DAVIO on a recording and write the odometry, report and plots."""
from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from tools.model_open import add_gpu_memory_argument, latency_arg

NAME = "run"
HELP = "run on an EuRoC folder or a simulated recording; write odometry.tum, report.json, plots"
DESCRIPTION = (
    "Replay a recording through DAVIO (KLT + MSCKF with its native initializer, plus the feed-forward "
    "DA3 start-up). The model is an exported DA3 ONNX graph (--model), or for recordings written by "
    "`davio simulate` the emulated DA3 (--emulated). Outputs go to --out: odometry.tum (IMU poses in the "
    "odometry frame), report.json (metrics, timings, counters, configuration, versions), config.toml, "
    "plots when ground truth exists, and with a model the dense map: map/ (the versioned submap archive, "
    "checkpointed at every commit) and map.ply (the fused 4 cm cloud)."
)


def _emulated_presets() -> list[str]:
    from models.emulated_da3.params import PRESETS

    return sorted(PRESETS)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from tools.live_view import add_view_argument

    p.add_argument("path", help="EuRoC ASL folder (sequence or mav0), a `davio simulate` folder, or a ROS 1 "
                                "/ ROS 2 bag (.bag, a bag folder, .db3, .mcap)")
    p.add_argument("--rig", metavar="FILE",
                   help="calibration: a Kalibr camchain, EuRoC sensor.yaml or folder, OpenVINS yaml (needed "
                        "for bags without a CameraInfo; replaces a folder's own sensor.yaml)")
    p.add_argument("--image-topic", metavar="TOPIC", help="bag image topic (default: auto-detected)")
    p.add_argument("--imu-topic", metavar="TOPIC", help="bag IMU topic (default: auto-detected)")
    p.add_argument("--out", default="davio_run",
                   help="output folder: must be new or empty (see --overwrite); the run is written into "
                        "OUT.partial/ and renamed to OUT/ when it ends, with run_status.json")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the previous run in --out (only a folder that holds a DAVIO run)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--model", metavar="ONNX", help="DA3 ONNX graph (made by `davio export-da3`)")
    add_gpu_memory_argument(p)
    g.add_argument("--emulated", metavar="PRESET", nargs="?", const="base", default=None,
                   choices=_emulated_presets(),
                   help="emulated DA3 (simulated recordings only): small, base or large, or <size>_upper "
                        "with the upper-bound pose errors (models/emulated_da3/PRESETS.md)")
    g.add_argument("--native-only", action="store_true", help="no feed-forward start-up and no map")
    p.add_argument("--no-map", action="store_true",
                   help="do not map (mapping runs whenever a depth model is given)")
    p.add_argument("--config", metavar="TOML", help="configuration file (see config.toml of a run)")
    add_prior_map_argument(p)
    p.add_argument("--strict", action="store_true",
                   help="every input repair (dropped, reordered or converted rows and images) is an error "
                        "naming the file and line, instead of being counted in report.json")
    p.add_argument("--withhold-extrinsics", action="store_true",
                   help="ignore the rig's camera-IMU extrinsics and time offset: hand-eye bring-up from the "
                        "camera's rotations (DA3's, or two-view fits of the tracked features without a "
                        "model), then online calibration")
    p.add_argument("--paced", action="store_true",
                   help="replay at sensor rate instead of as fast as possible")
    p.add_argument("--speed", type=float, default=1.0, help="pacing factor with --paced (> 0)")
    p.add_argument("--model-latency", type=latency_arg, default=0.5, metavar="S",
                   help="simulated model latency (sensor seconds, >= 0) when not paced; 'measured': one "
                   "timed call of the --model graph after its warm-up (e.g. 0.04 s on a GPU)")
    p.add_argument("--seconds", type=float, default=None, help="only the first S seconds (> 0)")
    p.add_argument("--json", action="store_true",
                   help="print the report as one JSON object on stdout (progress goes to stderr)")
    add_view_argument(p)


def add_prior_map_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--prior-map", metavar="RUN",
                   help="an earlier run of the same place (its folder, or its map/): this run's submaps are "
                        "localised in its map, and the poses published once localised are also written in "
                        "its frame (causal.prior.tum, final.prior.tum, alignment.json); needs a depth model")


def check_run_args(args: argparse.Namespace) -> None:
    """ConfigError for option values that cannot work (before any file is read)."""
    import math

    from runtime.errors import ConfigError
    from tools.model_open import MEASURED

    lat = getattr(args, "model_latency", None)
    if lat == MEASURED:
        if not getattr(args, "model", None):
            raise ConfigError("--model-latency measured times the --model graph: it needs --model ONNX")
    elif lat is not None and not (math.isfinite(lat) and lat >= 0):
        raise ConfigError(f"--model-latency must be a finite number of seconds >= 0 (got {lat!r})")
    sec = getattr(args, "seconds", None)
    if sec is not None and not (math.isfinite(sec) and sec > 0):
        raise ConfigError(f"--seconds must be a finite number > 0 (got {sec!r})")
    from tools.model_open import check_gpu_memory_args

    check_gpu_memory_args(args)
    speed = getattr(args, "speed", None)
    if speed is not None and not (math.isfinite(speed) and speed > 0):
        raise ConfigError(f"--speed must be > 0 (got {speed!r})")


def run(args: argparse.Namespace) -> int:
    from runtime.config import DavioConfig, load_davio_config
    from tools.run_folder import RunFolder
    from tools.run_outcome import interruptible

    check_run_args(args)
    config = load_davio_config(args.config) if args.config else DavioConfig()
    folder = RunFolder.prepare(args.out, overwrite=args.overwrite)
    with interruptible():
        rec, rig, model, model_desc = _open_inputs(args, config)
        if args.no_map:
            config = replace(config, mapping=replace(config.mapping, enabled=False))
        prior = prior_map(args, model, config)
        folder.create()
        with folder.discard_on_error():
            return _run(args, folder, rec, rig, model, model_desc, config, prior)


def prior_map(args: argparse.Namespace, model, config):
    """The PriorMapLocalizer of --prior-map (None without it); ConfigError when this run cannot map."""
    if not args.prior_map:
        return None
    import sys

    from runtime.errors import ConfigError
    from tools.map_archive.align import prior_map_localizer

    if model is None or not config.mapping.enabled:
        raise ConfigError("--prior-map localises this run's submaps in the earlier map: it needs a depth "
                          "model (--model or --emulated) and the mapping on (not --native-only or --no-map)")
    if not config.mapping.graph or not config.revisits.enabled:
        raise ConfigError("--prior-map needs the submaps' centre views, which the submap graph keeps for "
                          "revisits: set mapping.graph and revisits.enabled to true")
    from runtime.graph.relocalize import AlignConfig

    notes: list[str] = []
    loc = prior_map_localizer(Path(args.prior_map), notes, AlignConfig(gates=config.revisits))
    for n in notes:
        print(f"davio: prior map: note: {n}", file=sys.stderr)
    return loc


def _open_inputs(args: argparse.Namespace, config) -> tuple:
    """(recording, rig, model, model description) for the run, or a DavioError saying why not."""
    from runtime.errors import ConfigError
    from tools.run_io import open_recording

    given_rig = None
    if args.rig:
        from calib import load_rig

        given_rig = load_rig(args.rig)
    rec = open_recording(args.path, rebuild=not args.native_only, policy="strict" if args.strict else "drop",
                         rig=given_rig, image_topic=args.image_topic, imu_topic=args.imu_topic)
    rig = given_rig if given_rig is not None else rec.driver.rig
    if given_rig is None and rig is not None and rec.time_offset_s is not None and not rig.time_offset_s:
        rig = rig.replace(time_offset_s=rec.time_offset_s)      # a simulated folder's, from its manifest
    if given_rig is not None and given_rig.camera is None:
        raise ConfigError(f"--rig {args.rig}: holds no camera intrinsics (cam0.intrinsics withheld or null); "
                          "DAVIO needs them: give cam0's intrinsics, resolution and distortion in that file")
    if rig is None or rig.camera is None:
        where = "no CameraInfo in the bag" if rec.kind == "bag" else "no cam0/sensor.yaml"
        raise ConfigError(f"{args.path}: no camera calibration ({where}); DAVIO needs intrinsics: pass "
                          "--rig FILE (a Kalibr camchain, an EuRoC sensor.yaml or folder)")
    if hasattr(rec.driver, "expect_image_size"):   # a wrong-size first image is then skipped, as any other
        rec.driver.expect_image_size(rig.camera.width, rig.camera.height)
    if args.withhold_extrinsics:
        rig = rig.replace(T_IC=None, time_offset_s=None)
    model, model_desc = None, "none (native initializer only)"
    if args.model:
        from tools.model_open import MEASURED, measured_latency, open_da3

        # one-off session costs are paid here, at the start-up window's shape, not by the first window
        model, model_desc = open_da3(args, rig.camera, config.startup.window_images)
        if args.model_latency == MEASURED:
            args.model_latency = round(measured_latency(model, config.startup.window_images), 4)
            model_desc += f"; replay latency {args.model_latency:.3f} s (measured, one call)"
    elif args.emulated or (rec.kind == "simulated" and not args.native_only):
        if rec.kind != "simulated":
            raise ConfigError("--emulated needs a recording written by `davio simulate` (it reads the "
                              "simulator's ground truth); for real data pass --model DA3.onnx")
        from models.emulated_da3 import EmulatedDA3

        preset = args.emulated or "base"
        cam = rig.camera
        model = EmulatedDA3(rec.ground_truth_source, cam.K, cam.width, cam.height, preset=preset)
        model_desc = f"EMULATED DA3 ({preset}) from simulator ground truth -- not a real network"
    return rec, rig, model, model_desc


def _run(args, folder, rec, rig, model, model_desc: str, config, prior=None) -> int:
    import sys

    from tools.live_view import open_view
    from tools.pose_journal import PoseJournal, chain_poses
    from tools.run_io import imu_noise_note, rig_summary, write_run
    from tools.run_map import MapOutput
    from tools.run_outcome import conclude, judge
    from tools.run_session import run_pipeline

    map_out = MapOutput.create(folder.path, rig, model_desc, model, config)
    # with --json, stdout holds the JSON object only
    log = sys.stderr if args.json else sys.stdout
    defaulted = config.msckf.defaulted_imu_noise(rig.imu)
    print(f"davio run: {rec.description}\n  model: {model_desc}"
          + (f"\n  mapping: on (archive {folder.out / 'map'})" if map_out is not None else "")
          + (f"\n  prior map: {prior.source} ({len(prior.prior)} centre views)" if prior is not None else "")
          + (f"\n  {imu_noise_note(defaulted)}" if defaulted else ""), file=log)
    view = open_view(args.view)
    sink = None if map_out is None else map_out.sink
    journal = PoseJournal(folder.path)
    try:
        res = run_pipeline(rec.driver, model, config, paced=args.paced, speed=args.speed,
                           model_latency_s=args.model_latency, seconds=args.seconds, rig=rig,
                           map_sink=view.chain(sink) if view is not None else sink, keep_partial=True,
                           on_pose=journal if view is None else chain_poses(journal, view.on_pose),
                           prior_map=prior)
    finally:
        if view is not None:
            view.close()
        journal.close()
    if journal.failed:
        print(f"davio run: warning: the pose journal stopped ({journal.failed}); the run went on",
              file=sys.stderr)
    judge(res, rec.driver.report())
    gt = rec.driver.groundtruth()
    map_summary = map_out.finish() if map_out is not None else None
    report = write_run(folder.path, res.pipeline, res.scheduler, gt,
                       {"recording": rec.description, "model": model_desc, "status": res.status,
                        "status_reason": res.reason, "driver": rec.driver.report(), "map": map_summary,
                        "imu_noise_defaulted": defaulted,
                        "rig": rig_summary(rig, str(args.rig) if args.rig else f"the recording ({rec.kind})"),
                        "view": None if view is None else view.report(),
                        "replay": {"paced": bool(args.paced), "speed": args.speed,
                                   "model_latency_s": None if args.paced else args.model_latency}},
                       config)
    journal.close(remove=True)   # the run's own trajectories are written whole
    return conclude(folder, res, report, as_json=args.json, summary=_summary)


def _first_published_line(report: dict) -> str:
    """When the first state was published and by whom (and who publishes at the end, when another)."""
    tf = report.get("T_f_s")
    first, now = report.get("first_published_by"), report.get("published_by")
    at_end = "" if first is None or now == first else f" (at the end: {now or 'nobody, after a reset'})"
    return (f"first published state: {'none' if tf is None else f'{tf:.2f} s'} by {first or now or '-'}"
            f"{at_end}; {report['published_poses']} poses")


def _summary(report: dict, out: Path) -> None:
    m = report.get("metrics", {})
    print("  " + _first_published_line(report))
    if m and "ate_se3_m" not in m and m.get("ate_se3_error"):
        print(f"  ATE: not computed: {m['ate_se3_error']}")
    elif m:
        nan = float("nan")
        print(f"  ATE: {m.get('ate_se3_m', nan):.3f} m (se3), {m.get('ate_posyaw_m', nan):.3f} m (posyaw)")
        mc, mf = report.get("metrics_causal") or {}, report.get("metrics_final") or {}
        if report["pipeline"].get("mapping") is not None and mc:
            print(f"  ATE map frame: causal {mc.get('ate_se3_m', nan):.3f} m, "
                  f"final {mf.get('ate_se3_m', nan):.3f} m (se3)")
    for line in _recovery_lines(report):
        print(f"  {line}")
    bu = report["pipeline"].get("bringup")
    if bu is not None:
        state = "done" if bu["R_IC"] else "NOT done"
        rms = bu["fit_rms_deg"] or float("nan")
        source = "DA3" if bu.get("rotation_source", "model") == "model" else "two-view fits of the tracks"
        print(f"  hand-eye bring-up: {state} after {bu['windows_used']} windows, rotations from {source} "
              f"(fit RMS {rms:.2f} deg, rejections {bu['rejections'] or '{}'})")
        from runtime.bringup import gyro_blamed

        gyro = gyro_blamed(bu)
        if gyro:
            print(f"  GYROSCOPE SCALE: {bu['rejections']['gyro_scale']} bring-up windows refused, the first: "
                  f"{gyro}. Fix the IMU's units or scale")
    s = report["scheduler"]
    print(f"  tracking {s.get('tracking_ms_per_frame_median', float('nan')):.1f} ms/frame (median), "
          f"real-time factor {s.get('realtime_factor') or float('nan'):.2f}")
    mp = report["pipeline"].get("mapping")
    if mp is not None:
        print("  " + _mapping_line(mp, report.get("map") or {}))
    if report.get("prior_map") is not None:
        print("  " + _prior_line(report["prior_map"]))
    print(f"  outputs: {out}/odometry.tum, causal.tum, final.tum, poses.csv, report.json, config.toml"
          + (", plots" if m else "")
          + (", map/, map.ply" if (report.get("map") or {}).get("ply") else ""))


def _prior_line(pm: dict) -> str:
    """One console line: localised in the prior map or not, and why."""
    if pm["localized"]:
        t = pm["t"]
        after = pm["localized_after_s"]
        return (f"prior map: localised {'' if after is None else f'{after:.1f} s into the run '}(yaw "
                f"{pm['yaw_deg']:.2f} deg, t = ({t[0]:.3f}, {t[1]:.3f}, {t[2]:.3f}) m; {pm['agreeing']} "
                f"verified pairs agree); {pm['poses_in_prior_frame']} poses published in its frame -> "
                "causal.prior.tum, final.prior.tum"
                + (f"; a wrong lock was replaced {pm['switches']}x (a look-alike place outvoted; "
                   "causal.prior.tum holds the poses published before)" if pm.get("switches") else ""))
    return (f"prior map: NOT localised ({pm['reason']}; {pm['attempts']} candidate pairs tried, "
            f"{pm['verified']} verified)")


def _mapping_line(mp: dict, summary: dict) -> str:
    """One console line: windows mapped / offered, drops, rejections by reason, retained points."""
    rej = ", ".join(f"{k} x{v}" for k, v in sorted(mp["windows_rejected"].items())) or "none"
    sampled = max(mp["points_sampled"], 1)
    return (f"map: {mp['windows_accepted']}/{mp['windows_offered']} windows mapped, "
            f"{mp['windows_dropped_queue']} dropped (queue full), rejected: {rej}; "
            f"{mp['points_retained']} points kept ({100 * mp['rejected_confidence'] / sampled:.0f} % low "
            f"confidence, {100 * mp['rejected_multiview'] / sampled:.0f} % failed the multi-view test, "
            f"{100 * mp.get('points_unverified', 0) / sampled:.0f} % kept seen by one image only); "
            f"{summary.get('voxels', 0)} voxels in map.ply" + _graph_text(mp.get("graph"))
            + _archive_stopped_text(summary.get("archive_stopped")))


def _archive_stopped_text(stopped: dict | None) -> str:
    if not stopped:
        return ""
    return (f"\n  WARNING: the map archive stopped at map version {stopped['map_version']} "
            f"({stopped['reason']}: {stopped['free_mb']:g} MB); {stopped['commits_skipped']} later commits "
            "were not archived, and map.ply holds the map up to then")


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
    "unreadable_images": "unreadable images", "gaps": "gaps",
}


EXTRINSICS_WARNING_WINDOWS = 2
"""Windows refused as extrinsics_rotation before the console blames the rig's rotation: one window is one
hand-eye fit of four rotations (`davio bench rig-checks` saw no such window with the right rotation, and
several per recording with it inverted wherever the rig turns about two axes: BENCHMARKS.md "Start-up
checks of the rig")."""


def _time_offset_line(startup: dict, rig_offset_s: float | None) -> str | None:
    """The console's word on a camera-IMU time offset the start-up found far from the rig's: adopted,
    solved at, or only found (runtime.ffinit.time_offset_check); None when it found none."""
    found = startup.get("time_offset_findings") or 0
    if not found:
        return None
    rig_ms = (rig_offset_s or 0.0) * 1e3
    adopted = startup.get("time_offset_adopted_s")
    first = startup.get("time_offset_first") or startup.get("ff_time_offset_first") or \
        (startup.get("ff_rejection_first") or {}).get("time_offset", "") or "-"
    rig = f"(the rig says {rig_ms:+.1f} ms)"
    if adopted is not None:
        what = f"adopted {adopted * 1e3:+.1f} ms {rig}"
    elif startup.get("ff_time_offset_s") is not None:
        what = f"a window was solved at {startup['ff_time_offset_s'] * 1e3:+.1f} ms {rig}"
    else:
        what = "not adopted"
    windows = "1 window fits" if found == 1 else f"{found} windows fit"
    return (f"CAMERA-IMU TIME OFFSET: {windows} another offset, {what}; the first: {first}. Put "
            "the offset in the rig file (Kalibr timeshift_cam_imu: t_imu = t_cam + shift)")


ESTIMATED_OFFSET_NOTE_S = 0.005
"""The console names the filter's estimate of the camera-IMU time offset when it ends at least this far (s),
and three of its standard deviations, from the offset in use (the rig's, or the one the start-up adopted):
about a sample period of a 200 Hz IMU, and five times the estimate's spread on a right rig (BENCHMARKS
"The camera-IMU time offset in the filter's state")."""


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


def _recovery_lines(report: dict) -> list[str]:
    """One console line per kind of recovery the run made (input repairs, initializer rejections,
    filter resets), so that nothing counted in report.json goes unnoticed on the console."""
    lines = input_lines(report.get("driver"))
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
    errors = (report["pipeline"].get("tracking") or {}).get("ff_exceptions") or []
    if errors:
        lines.append(f"feed-forward model calls failed: {len(errors)} (first: {errors[0]})")
    map_errors = (report["pipeline"].get("mapping") or {}).get("model_errors") or []
    if map_errors:
        lines.append(f"mapping model calls failed: {len(map_errors)} (first: {map_errors[0]})")
    startup = report["pipeline"].get("startup") or {}
    if startup.get("ff_rejections"):
        reasons = ", ".join(f"{k} x{v}" for k, v in sorted(startup["ff_rejections"].items()))
        lines.append(f"feed-forward windows rejected: {reasons}")
        first = startup.get("ff_rejection_first") or {}
        if startup["ff_rejections"].get("gyro_scale"):
            lines.append(f"GYROSCOPE SCALE: {startup['ff_rejections']['gyro_scale']} windows refused, the "
                         f"first: {first.get('gyro_scale', '')}. Fix the IMU's units or scale; every filter "
                         "integrates them too")
        if startup["ff_rejections"].get("extrinsics_rotation", 0) >= EXTRINSICS_WARNING_WINDOWS:
            lines.append(f"CAMERA-IMU ROTATION: {startup['ff_rejections']['extrinsics_rotation']} windows "
                         f"refused, the first: {first.get('extrinsics_rotation', '')}. Check the rig file's "
                         "T_cam_imu / T_imu_cam, or run with --withhold-extrinsics to estimate it")
    check = report["pipeline"].get("rig_check") or {}     # without a model: from the tracked features
    if check.get("gyro_scale"):
        lines.append(f"GYROSCOPE SCALE (tracked features): {check['gyro_scale']}. Fix the IMU's units or "
                     "scale; the filter integrates them")
    if check.get("error"):
        lines.append(f"rig check from the tracked features ended early: {check['error']}")
    if check.get("extrinsics_rotation"):
        lines.append(f"CAMERA-IMU ROTATION (tracked features): {check['extrinsics_rotation']}. Check the rig "
                     "file's T_cam_imu / T_imu_cam, or run with --withhold-extrinsics to estimate it")
    rig_offset_s = (report.get("rig") or {}).get("time_offset_s")
    for line in (_time_offset_line(startup, rig_offset_s),
                 _estimated_offset_line(report["pipeline"].get("filter") or {}, startup, rig_offset_s)):
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
