"""`davio simulate`: write a simulated camera-IMU recording (EuRoC ASL folder + exact ground truth)."""

from __future__ import annotations

import argparse

from tools.cli_types import count, number

NAME = "simulate"
HELP = "simulate a camera-IMU recording with exact ground truth (EuRoC folder)"
DESCRIPTION = (
    "Render a simulated recording into a EuRoC ASL folder: cam0 images (752x480 EuRoC camera with its lens "
    "distortion), imu0 at 200 Hz, state ground truth, depth0 maps (uint16 mm), scene_points.ply and "
    "manifest.json. Motion from a preset (default 'euroc': 2 s at rest, take-off, flight) or from a "
    "trajectory file; with --imu the real IMU stream is replayed against that trajectory "
    "(EuRoC-trajectory mode)."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from drivers.sim.imu_synth import IMU_PROFILES
    from drivers.sim.motion import DEFAULT_PRESET, PRESETS

    p.add_argument(
        "--preset",
        default=DEFAULT_PRESET,
        choices=sorted(PRESETS),
        help="motion preset: " + "; ".join(f"{k}: {v.description}" for k, v in PRESETS.items()),
    )
    p.add_argument(
        "--seconds",
        type=number,
        default=None,
        help="duration in s (preset default 20; trajectory default: all of it)",
    )
    p.add_argument("--start", type=number, default=0.0, help="seconds skipped at the start of --trajectory")
    p.add_argument("--seed", type=count(0), default=0, help="seed of motion, scene and noise")
    p.add_argument("--style", default="room", choices=["room", "hall"], help="scene style")
    p.add_argument(
        "--trajectory",
        metavar="FILE",
        default=None,
        help="trajectory T_WI to follow: EuRoC state CSV or TUM file, or a euroc_imu_gt folder",
    )
    p.add_argument(
        "--imu",
        metavar="FILE",
        default=None,
        help="real EuRoC imu0 CSV replayed against --trajectory (EuRoC-trajectory mode)",
    )
    p.add_argument(
        "--camera-stamps",
        metavar="FILE",
        default=None,
        help="camera stamps (ns per line) for --imu mode (default: cam0_timestamps.txt beside --imu)",
    )
    p.add_argument(
        "--groundtruth",
        dest="groundtruth_mode",
        default=None,
        choices=["imu-consistent", "as-recorded"],
        help="EuRoC-trajectory mode (a real IMU replayed): render from the ground truth without its position "
             "jumps and with the "
             "bias-corrected gyro's attitude held to it over 1 s (default; images and IMU agree as on a real "
             "rig), or from the ground truth as recorded (its jumps and attitude spells move the images "
             "where the IMU does not)",
    )
    p.add_argument(
        "--scene",
        dest="scene_span",
        default="recording",
        choices=["recording", "trajectory"],
        help="what the scene is built around (--trajectory only): the rendered part (default), or the whole "
             "trajectory file, so that recordings cut from one file at different --start see one place "
             "(sessions to align with `davio map align`)",
    )
    p.add_argument(
        "--time-offset",
        type=number,
        default=0.0,
        metavar="S",
        help="camera-to-IMU clock offset, t_imu = t_cam + S (kept in manifest.json, since an ASL sensor.yaml "
             "has no field for it; `davio run` uses it unless --rig gives a rig file)",
    )
    p.add_argument(
        "--motion-blur", type=count(1), default=1, metavar="N", help="renders averaged per frame (1 = off)"
    )
    p.add_argument(
        "--imu-model",
        default="datasheet",
        choices=IMU_PROFILES,
        help="synthetic IMU errors (presets and trajectory files without --imu): the rig's datasheet noise "
             "densities and bias random walk (default), or those plus the slowly varying in-flight errors "
             "measured on the real EuRoC IMU (its drift from the truth over 0.25-4 s, BENCHMARKS.md)",
    )
    p.add_argument(
        "--exact",
        action="store_true",
        help="noise-free images and IMU (no image noise, exposure changes, vignetting or IMU errors)",
    )
    p.add_argument("--no-depth", action="store_true", help="skip the depth0 maps")
    p.add_argument(
        "--out", required=True, metavar="DIR", help="output folder (created; must be new or empty)"
    )
    p.add_argument("--json", action="store_true", help="print the manifest as one JSON object on stdout")


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace
    from pathlib import Path

    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from drivers.sim.imu_synth import ImuErrorModel
    from drivers.sim.recording import SimConfig, SimRecording  # it checks --seconds and --start
    from drivers.sim.render import ImageOptions
    from drivers.sim.threads import prefer_workqueue_layer
    from drivers.sim.writer import write_euroc
    from runtime.errors import ConfigError
    from runtime.json_out import strict_dumps
    from tools.run_folder import check_writable_target, holds_files

    out = Path(args.out)
    check_writable_target(out)
    if out.is_dir() and holds_files(out):
        raise ConfigError(f"--out {out} is not empty; choose a new or empty folder")
    if args.start != 0.0 and not args.trajectory:
        raise ConfigError("--start applies to --trajectory (the seconds of the file skipped); a preset "
                          "starts at its beginning")
    prefer_workqueue_layer()  # idle OpenMP threads spin: costly on a shared 2-core machine
    con = Console(stderr=True)
    image = ImageOptions.exact() if args.exact else ImageOptions()
    image = replace(image, motion_blur_samples=args.motion_blur)
    cfg = SimConfig(
        preset=args.preset,
        seconds=args.seconds,
        seed=args.seed,
        style=args.style,
        time_offset_s=args.time_offset,
        image=image,
        start_s=args.start,
        groundtruth_mode=args.groundtruth_mode or "imu-consistent",
        imu_errors=ImuErrorModel.noise_free() if args.exact else None,
        imu_profile=args.imu_model,
        scene_span=args.scene_span,
    )
    if args.scene_span != "recording" and not args.trajectory:
        raise ConfigError("--scene trajectory needs --trajectory (a preset has no file to build around)")
    if args.exact and args.imu_model != "datasheet":
        raise ConfigError("--exact makes the IMU noise-free; it cannot be combined with --imu-model")
    if args.imu and not args.trajectory:
        raise ConfigError("--imu needs --trajectory (the ground truth the IMU belongs to)")
    if args.camera_stamps and not args.imu:
        raise ConfigError("--camera-stamps applies with --imu (a real IMU replayed); a synthetic recording "
                          "stamps its own frames")
    if args.groundtruth_mode and not (args.imu or (args.trajectory and Path(args.trajectory).is_dir())):
        raise ConfigError("--groundtruth applies to EuRoC-trajectory mode only (a real IMU replayed: "
                          "--trajectory FOLDER, or --trajectory FILE --imu FILE)")
    real_imu = bool(args.imu or (args.trajectory and Path(args.trajectory).is_dir()))
    if real_imu and args.imu_model != "datasheet":
        raise ConfigError("--imu-model applies to a synthetic IMU; EuRoC-trajectory mode replays the real "
                          "one")
    try:            # after the checks, before the rendering (/sys refuses it even to root)
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"--out {out}: cannot create the folder ({exc.strerror or exc})") from None
    con.print("[bold]davio simulate[/]: building scene and motion ...")
    if args.trajectory is None:
        rec = SimRecording.from_preset(replace(cfg, seconds=args.seconds or 20.0))
    elif Path(args.trajectory).is_dir():
        rec = SimRecording.from_euroc_imu_gt(args.trajectory, cfg)
    else:
        rec = SimRecording.from_trajectory(
            args.trajectory, cfg, imu_path=args.imu, camera_stamps_path=args.camera_stamps
        )
    info = rec.info
    con.print(
        f"mode {info['mode']}, {info['seconds']:.1f} s, {len(rec)} frames, {len(rec.imu)} IMU samples, "
        f"scene {rec.scene.summary()['room_size_m']} m with {rec.scene.n_boxes - 1} boxes"
    )
    for note in info.get("notes", []):
        con.print(f"note: {note}")
    with Progress(
        TextColumn("rendering"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total} frames"),
        TimeRemainingColumn(),
        console=con,
    ) as bar:
        task = bar.add_task("render", total=len(rec))
        manifest = write_euroc(
            rec,
            args.out,
            depth=not args.no_depth,
            progress=lambda done, total: bar.update(task, completed=done),
        )
    con.print(f"wrote {args.out}: {manifest['counts']}")
    for note in manifest["notes"][len(info.get("notes", [])):]:     # the trajectory's were said above
        con.print(f"note: {note}")
    if args.json:
        print(strict_dumps(manifest))
    return 0
