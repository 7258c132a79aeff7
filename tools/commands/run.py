"""`davio run PATH`: run DAVIO on a recording and write the odometry, report and plots."""
from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from tools.cli_types import number
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
    p.add_argument("--speed", type=number, default=1.0, help="pacing factor with --paced (> 0)")
    p.add_argument("--model-latency", type=latency_arg, default=0.5, metavar="S",
                   help="simulated model latency (sensor seconds, >= 0) when not paced; 'measured': one "
                   "timed call of the --model graph after its warm-up (e.g. 0.04 s on a GPU)")
    p.add_argument("--seconds", type=number, default=None,
                   help="only the first S seconds (> 0), counted from where both images and IMU have begun")
    p.add_argument("--json", action="store_true",
                   help="print the report as one JSON object on stdout (progress goes to stderr)")
    add_view_argument(p)
    add_stream_argument(p)


def add_stream_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--stream", metavar="udp://HOST:PORT",
                   help="send each published pose and each run event to HOST:PORT as it happens, one UDP "
                        "datagram of JSON each (tools/pose_stream.py: odometry-, map- and prior-frame pose, "
                        "velocity, covariance); never blocks the run")


def add_prior_map_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--prior-map", metavar="RUN",
                   help="an earlier run of the same place (its folder, or its map/): this run's submaps are "
                        "localised in its map, and the poses published once localised are also written in "
                        "its frame (causal.prior.tum, final.prior.tum, alignment.json); needs a depth model")


def check_run_args(args: argparse.Namespace) -> None:
    """ConfigError for option values that cannot work (before any file is read)."""
    import math

    from runtime.errors import ConfigError
    from tools.model_open import MAX_MODEL_LATENCY_S, MEASURED

    lat = getattr(args, "model_latency", None)
    if lat == MEASURED:
        if not getattr(args, "model", None):
            raise ConfigError("--model-latency measured times the --model graph: it needs --model ONNX")
    elif lat is not None and not (math.isfinite(lat) and 0 <= lat <= MAX_MODEL_LATENCY_S):
        raise ConfigError(f"--model-latency must be a number of seconds from 0 to {MAX_MODEL_LATENCY_S:g} "
                          f"(got {lat!r})")
    sec = getattr(args, "seconds", None)
    if sec is not None and not (math.isfinite(sec) and sec > 0):
        raise ConfigError(f"--seconds must be a finite number > 0 (got {sec!r})")
    from tools.model_open import check_gpu_memory_args

    check_gpu_memory_args(args)
    speed = getattr(args, "speed", None)
    if speed is not None and not (math.isfinite(speed) and speed > 0):
        raise ConfigError(f"--speed must be > 0 (got {speed!r})")
    if getattr(args, "stream", None) is not None:   # a host that does not resolve: before any work
        from tools.pose_stream import resolve_stream_url

        resolve_stream_url(args.stream)
    if getattr(args, "prior_map", None) and getattr(args, "out", None):
        check_prior_not_out(args.prior_map, args.out)


def check_prior_not_out(prior_map: str, out: str) -> None:
    """ConfigError when --out, or the `OUT.partial` folder a run writes first, is or holds the --prior-map
    folder: the run replaces its --out and would delete the map it localises in (the only copy, and its
    alignment.json would then name this run's own map as the prior)."""
    from runtime.errors import ConfigError

    prior = Path(prior_map).resolve()
    target = Path(out).resolve()
    for folder in (target, target.with_name(target.name + ".partial")):
        if prior == folder or folder in prior.parents:
            raise ConfigError(f"--prior-map {prior_map} lies in this run's --out ({folder}): the run would "
                              f"replace the map it localises in; give another --out")


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
    from tools.commands.map import resolve
    from tools.map_archive.format import JOURNAL_NAME

    archive, _ = resolve(Path(args.prior_map))    # a run folder without a map/ is said as such
    notes: list[str] = []
    if (archive / JOURNAL_NAME).exists():
        notes.append(f"{archive} has a pending journal: its run was killed, or is still writing it; the map "
                     "as of its last commit is used")
    loc = prior_map_localizer(archive, notes, AlignConfig(gates=config.revisits))
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

    from tools.run_io import imu_noise_note, rig_summary, write_run
    from tools.run_map import MapOutput
    from tools.run_outcome import conclude, finishing, judge
    from tools.run_session import run_pipeline
    from tools.run_sinks import RunSinks
    from tools.run_summary import summary

    map_out = MapOutput.create(folder.path, rig, model_desc, model, config)
    # with --json, stdout holds the JSON object only
    log = sys.stderr if args.json else sys.stdout
    defaulted = config.msckf.defaulted_imu_noise(rig.imu)
    print(f"davio run: {rec.description}\n  model: {model_desc}"
          + (f"\n  mapping: on (archive {folder.out / 'map'})" if map_out is not None else "")
          + (f"\n  prior map: {prior.source} ({len(prior.prior)} centre views)" if prior is not None else "")
          + (f"\n  {imu_noise_note(defaulted)}" if defaulted else ""), file=log)
    sinks = RunSinks(folder.path, args.view, args.stream)
    try:
        res = run_pipeline(rec.driver, model, config, paced=args.paced, speed=args.speed,
                           model_latency_s=args.model_latency, seconds=args.seconds, rig=rig,
                           map_sink=sinks.map_sink(None if map_out is None else map_out.sink),
                           keep_partial=True, on_pose=sinks.on_pose, prior_map=prior, on_event=sinks.on_event)
        finishing()         # a signal from here on would only lose the outputs
    finally:
        sinks.close()
    sinks.warn("davio run")
    judge(res, rec.driver.report())
    gt = rec.driver.groundtruth()
    map_summary = map_out.finish() if map_out is not None else None
    report = write_run(folder.path, res.pipeline, res.scheduler, gt,
                       {"recording": rec.description, "model": model_desc, "status": res.status,
                        "status_reason": res.reason, "driver": rec.driver.report(), "map": map_summary,
                        "imu_noise_defaulted": defaulted,
                        "rig": rig_summary(rig, str(args.rig) if args.rig else f"the recording ({rec.kind})"),
                        **sinks.report(),
                        "replay": {"paced": bool(args.paced), "speed": args.speed,
                                   "model_latency_s": None if args.paced else args.model_latency}},
                       config)
    sinks.journal.close(remove=True)   # the run's own trajectories are written whole
    return conclude(folder, res, report, as_json=args.json, summary=summary)
