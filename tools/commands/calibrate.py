"""`davio calibrate SOURCE --out rig.yaml`: camera–IMU extrinsics and time offset from a recording."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from tools.cli_types import number
from tools.model_open import add_gpu_memory_argument

NAME = "calibrate"
HELP = "estimate the camera-IMU extrinsics and time offset of a recording; write a Kalibr camchain"
DESCRIPTION = (
    "Calibrate the camera-IMU rig from a recording: the hand-eye bring-up (R_IC and the gyro bias from "
    "the camera's vs preintegrated IMU rotations) and the filter's online refinement of rotation, lever "
    "arm and time offset. The camera's rotations come from DA3 (--model, or --emulated on a `davio "
    "simulate` folder, its default) or, with no model (--two-view; the default on other recordings and "
    "live modules), from two-view fits of the tracked features: no network needed. SOURCE is an EuRoC "
    "folder, a `davio simulate` folder, a ROS 1 / ROS 2 bag, or a live module: `oak` (depthai) or `uvc` "
    "(a UVC camera and a serial IMU, --imu-port; the options of `davio live`), moved by hand until "
    "--seconds or Ctrl-C. The intrinsics come from the recording's own calibration, an OAK's factory "
    "calibration, or --rig (its camera part is kept; its extrinsics and time offset are withheld and "
    "estimated; an OAK's factory extrinsics are shown beside the estimate). Writes --out (a Kalibr "
    "camchain: cam0 intrinsics, T_cam_imu, timeshift_cam_imu with t_imu = t_cam + shift), the IMU noise "
    "YAML beside it (imu.yaml, or the camchain's name with 'camchain' -> 'imu', so that calib.load_rig "
    "finds it), <out stem>.report.json (bring-up windows, residuals and rejections, rotation excitation, "
    "the final estimate with its 1-sigma, convergence over time), <out stem>.convergence.png and <out "
    "stem>.events.jsonl (the run's events as they happen: a reset, a rig finding, ...). Refuses (exit 3, "
    "one line saying what was observed, no rig file written; the report is still written) when the "
    "rotation excitation is insufficient (fewer than two principal axes at --min-axis-rate-dps), the data"
    " is too short for the bring-up (under --min-seconds), the bring-up never completes, the final "
    "1-sigma exceeds --max-rot-std-deg / --max-lever-std-m / --max-offset-std-ms, or the lever arm is "
    "still moving (--max-lever-drift-m over the last --settle-window-s of the final filter segment, which"
    " must be that long)."
)

#: exit status of a refusal (1: an error, 2: bad arguments)
EXIT_REFUSED = 3
#: the refusal thresholds' options: tools.calibrate.checks.Thresholds' field (--field-name), metavar, help
THRESHOLD_OPTIONS = (
    ("min_axis_rate_dps", "DEG_S", "refuse unless two principal rotation axes of the gyro stream reach this "
     "RMS rate"),
    ("min_seconds", "S", "a run whose bring-up did not complete within fewer seconds of data is refused as "
     "too short"),
    ("max_rot_std_deg", "DEG", "refuse when the final rotation 1-sigma (worst axis) exceeds this"),
    ("max_lever_std_m", "M", "refuse when the final lever-arm 1-sigma (worst axis) exceeds this"),
    ("max_offset_std_ms", "MS", "refuse when the final time-offset 1-sigma exceeds this"),
    ("max_lever_drift_m", "M", "refuse when the lever arm came farther than this from its final value over "
     "the last --settle-window-s (still converging)"),
    ("settle_window_s", "S", "the span of the final filter segment over which the lever arm must have "
     "settled (a shorter final segment is refused)"),
)


def _emulated_presets() -> list[str]:
    from models.emulated_da3.params import PRESETS

    return sorted(PRESETS)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from tools.calibrate.checks import Thresholds

    th = Thresholds()
    p.add_argument(
        "source",
        help="EuRoC ASL folder, a `davio simulate` folder, a ROS 1 / ROS 2 bag (.bag, a bag folder, "
        ".db3, .mcap), or a live module: oak or uvc (see the device options below)",
    )
    p.add_argument(
        "--out",
        required=True,
        metavar="RIG.yaml",
        help="the Kalibr camchain to write (refused if it exists, unless --overwrite)",
    )
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--model", metavar="ONNX", help="DA3 ONNX graph (made by `davio export-da3`)")
    add_gpu_memory_argument(p)
    g.add_argument(
        "--emulated",
        metavar="PRESET",
        nargs="?",
        const="base",
        default=None,
        choices=_emulated_presets(),
        help="emulated DA3 (simulated recordings only; the default there): small, base, large, "
        "or <size>_upper",
    )
    g.add_argument(
        "--two-view",
        action="store_true",
        help="no depth model: the bring-up's camera rotations from two-view fits of the tracked features "
        "(the default without --model on real recordings and live modules)",
    )
    p.add_argument(
        "--rig",
        metavar="FILE",
        help="calibration whose camera intrinsics are used (Kalibr camchain, EuRoC sensor.yaml or "
        "folder, OpenVINS yaml); its extrinsics and time offset are ignored",
    )
    p.add_argument("--image-topic", metavar="TOPIC", help="bag image topic (default: auto-detected)")
    p.add_argument("--imu-topic", metavar="TOPIC", help="bag IMU topic (default: auto-detected)")
    p.add_argument("--seconds", type=number, default=None,
                   help="only the first S seconds (> 0), counted from where images and IMU have begun")
    p.add_argument("--config", metavar="TOML", help="configuration file (see config.toml of a run)")
    p.add_argument("--strict", action="store_true", help="every input repair is an error")
    p.add_argument(
        "--model-latency",
        type=number,
        default=0.5,
        metavar="S",
        help="simulated model latency (sensor seconds, >= 0; without a model the bring-up's fits take "
        "the replay's 0.1 s solve latency)",
    )
    for field, metavar, text in THRESHOLD_OPTIONS:
        p.add_argument(f"--{field.replace('_', '-')}", type=number, default=getattr(th, field),
                       metavar=metavar, help=text)
    p.add_argument("--no-plots", action="store_true", help="do not draw the convergence plots")
    from tools.commands.live import add_device_arguments

    dev = p.add_argument_group("live module (SOURCE oak or uvc)")
    add_device_arguments(dev)
    p.add_argument(
        "--json",
        action="store_true",
        help="print the report as one JSON object on stdout (progress goes to stderr)",
    )


def check_args(args: argparse.Namespace) -> None:
    """ConfigError for option values that cannot work and outputs that must not be replaced (before any
    file is read)."""
    from runtime.errors import ConfigError
    from tools.calibrate.output import paths_for
    from tools.model_open import check_gpu_memory_args

    check_gpu_memory_args(args)
    sec = args.seconds
    if sec is not None and not (math.isfinite(sec) and sec > 0):
        raise ConfigError(f"--seconds must be a finite number > 0 (got {sec!r})")
    from tools.model_open import MAX_MODEL_LATENCY_S

    if not (math.isfinite(args.model_latency) and 0 <= args.model_latency <= MAX_MODEL_LATENCY_S):
        raise ConfigError(f"--model-latency must be a number of seconds from 0 to {MAX_MODEL_LATENCY_S:g} "
                          f"(got {args.model_latency!r})")
    for opt, _, _ in THRESHOLD_OPTIONS:
        v = getattr(args, opt)
        if not (math.isfinite(v) and v > 0):
            raise ConfigError(f"--{opt.replace('_', '-')} must be a finite number > 0 (got {v!r})")
    out = Path(args.out)
    if out.is_dir():
        raise ConfigError(
            f"--out {out} is a folder: name the camchain file to write (e.g. {out / 'camchain.yaml'})"
        )
    if out.suffix.lower() not in (".yaml", ".yml"):
        raise ConfigError(f"--out {out}: the camchain must be a .yaml file")
    if paths_for(out)["imu"] == out:
        raise ConfigError(f"--out {out}: the IMU calibration is written as {out.name} beside the camchain; "
                          "name the camchain itself, e.g. camchain.yaml")
    if not args.overwrite:
        paths = paths_for(out)
        existing = [str(p) for p in paths.values() if p.exists() or p.is_symlink()]
        lone = paths["events"].exists() and not paths["report"].exists()
        if existing:
            raise ConfigError(f"--out {out}: {', '.join(existing)} exist(s)"
                              + (f" ({paths['events'].name} without a report beside it: the events of a "
                                 "calibration that failed, or of one still running)" if lone else "")
                              + "; pass --overwrite to replace")
    from tools.output_file import check_output_file

    source = Path(str(args.source))
    recording = source.is_dir() and ((source / "mav0").is_dir() or (source / "metadata.yaml").is_file())
    if recording and source.resolve() in out.resolve().parents:
        raise ConfigError(f"--out {out}: lies inside the recording {source}; write the calibration elsewhere")
    rig_file = []
    if getattr(args, "rig", None):   # the --rig file and the IMU file load_rig reads beside it
        from calib.io import find_imu_yaml

        rig = Path(args.rig)
        if rig.is_dir() and rig.resolve() in out.resolve().parents:
            raise ConfigError(f"--out {out}: lies inside the --rig folder {rig}, which this command reads; "
                              "write the calibration elsewhere")
        rig_file = [rig] + [p for p in [None if rig.is_dir() else find_imu_yaml(rig)] if p is not None]
    for p in paths_for(out).values():   # never a device, a FIFO, or the --rig file it reads
        check_output_file(p, "--out", (p.suffix.lower(),), overwrite=True, inputs=rig_file, new_folder=True)


def run(args: argparse.Namespace) -> int:
    from runtime.config import DavioConfig, load_davio_config
    from tools.calibrate.checks import Thresholds
    from tools.calibrate.core import calibrate, stderr_alert, stderr_progress
    from tools.run_outcome import finishing, interruptible

    check_args(args)
    config = load_davio_config(args.config) if args.config else DavioConfig()
    th = Thresholds(**{field: getattr(args, field) for field, _, _ in THRESHOLD_OPTIONS})
    from tools.calibrate.output import paths_for
    from tools.calibrate.sources import is_live, open_inputs, open_live

    log = sys.stderr if args.json else sys.stdout
    live = is_live(args.source)
    paths = paths_for(Path(args.out))
    events_path = paths["events"]
    made = [d for d in [events_path.parent, *events_path.parent.parents] if not d.exists()]
    report_before = _file_id(paths["report"])
    event_file = None

    def begin() -> None:
        """Start a live module, then say what runs and open the events file: a module that fails to
        start is one error line and leaves an earlier calibration's events file as it was."""
        nonlocal event_file
        if live:
            driver.start()
        print(
            f"davio calibrate: {what}\n  model: {desc}\n  extrinsics and time offset withheld: "
            "hand-eye bring-up, then online calibration"
            + ("\n  move the module about at least two axes; Ctrl-C (or --seconds) ends the data"
               if live else ""),
            file=log,
            flush=True,
        )
        event_file = open_event_file(events_path)

    def on_event(event) -> None:   # live: the file opens once the module started
        event_file(event)          # the session says nothing before its data: the file is open by then

    try:
        with interruptible():
            if live:
                from tools.commands.live import describe_device

                driver, rig, model, desc, reference = open_live(args, config)
                what = f"live {describe_device(args)}"
            else:
                rec, rig, model, desc, reference = open_inputs(args)
                driver, what = rec.driver, rec.description
            try:
                if not live:        # a recording: said before the session's set-up
                    begin()
                run_ = calibrate(
                    driver.events(),
                    rig,
                    model,
                    config,
                    seconds=args.seconds,
                    model_latency_s=args.model_latency,
                    progress=stderr_progress,
                    alert=stderr_alert,
                    live=live,
                    on_event=on_event if live else event_file,
                    before_data=begin if live else None,   # a module starts once the session is made
                )
            finally:
                if event_file is not None:
                    event_file.close()
                if live:                # also when the banner or the events file failed
                    driver.stop()
            finishing("writing the calibration")      # a signal from here on would only lose it
            if event_file.failed:
                print(f"davio calibrate: warning: the events file stopped ({event_file.failed}); the run "
                      "went on", file=sys.stderr)
            return finish(args, run_, rig, th, desc, what, reference, log, driver_report=driver.report(),
                          events_stopped=event_file.failed)
    except BaseException:
        if _file_id(paths["report"]) == report_before:     # no report of this run follows
            discard_failed_events(event_file, made, paths["report"])
        raise


def _file_id(path: Path) -> tuple[int, int] | None:
    """(inode, modification time in ns) of `path`, None when absent: a report written since differs."""
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_ino, st.st_mtime_ns


def open_event_file(path: Path):
    """tools.event_output.EventFile at `path` (its folder made as `davio run --out` makes one), or a
    ConfigError saying why it cannot be written."""
    from runtime.errors import ConfigError
    from tools.event_output import EventFile

    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        return EventFile(path.parent, name=path.name)
    except OSError as exc:
        raise ConfigError(f"--out: cannot write the events file {path}: {exc.strerror or exc}") from None


def discard_failed_events(event_file, made: list[Path], report: Path) -> None:
    """After a run that stopped with an error or Ctrl-C before writing its report: an events file holding
    events stays (it says what happened before; a rerun needs --overwrite, as after a failed `davio run`)
    and the run says where it is, and that a `report` beside it is an earlier calibration's; an empty one
    goes, and so do the folders this run made when they are left empty."""
    if event_file is not None and event_file.written == 0:
        event_file.path.unlink(missing_ok=True)
        if report.exists():     # its events file was opened (emptied) by this run
            print(f"davio calibrate: {report.name} is from an earlier calibration; its events file was "
                  "replaced by this run's, which held no event, and removed", file=sys.stderr)
    elif event_file is not None:
        earlier = f" ({report.name} beside it is from an earlier calibration)" if report.exists() else ""
        print(f"davio calibrate: the run's events up to where it stopped are in {event_file.path}{earlier}",
              file=sys.stderr)
    for folder in made:             # deepest first
        try:
            folder.rmdir()
        except OSError:             # not empty, or already gone
            break


def finish(
    args: argparse.Namespace, run_, rig, th, model_desc: str, recording: str, reference: dict, log,
    driver_report: dict | None = None, events_stopped: str | None = None,
) -> int:
    """Judge the run, write the report (always), the camchain (only when accepted) and the plots. The
    driver's input repairs go into the report ("driver") and on the console, as `davio run` says them;
    `events_stopped` says why the events file stopped during the run (report["files"]["events_stopped"])."""
    from runtime.files import atomic_write_text
    from runtime.json_out import strict_dumps
    from tools.calibrate.checks import judge
    from tools.calibrate.output import paths_for
    from tools.calibrate.report import build_report, write_outputs

    verdict = judge(run_, th)
    paths = paths_for(Path(args.out))
    paths["report"].parent.mkdir(parents=True, exist_ok=True)   # a new folder, as `davio run --out` makes
    report = build_report(run_, verdict, th, model_desc, recording, reference, paths)
    report["driver"] = driver_report
    report["files"]["events_stopped"] = events_stopped
    if verdict.ok:
        write_outputs(run_, rig, paths, report)
    else:   # a refused run writes no rig: say so when an earlier one is left where this one would go
        stale = [str(paths[k]) for k in ("camchain", "imu") if paths[k].exists()]
        report["stale_rig_files_left"] = stale
        if stale:
            print(f"davio calibrate: warning: {', '.join(stale)} not replaced: left from an earlier "
                  "calibration, not this one", file=sys.stderr)
    if not args.no_plots and run_.samples:
        from tools.calibrate.output import plot_convergence

        title = f"davio calibrate: {recording[:110]}\n{model_desc[:110]}"
        report["files"]["plot"] = str(plot_convergence(paths["plot"], report["convergence"], title))
    atomic_write_text(paths["report"], strict_dumps(report, indent=1))
    if args.json:
        print(strict_dumps(report))
    else:
        from tools.calibrate.report import summary_lines
        from tools.run_summary import input_lines

        for line in [*input_lines(driver_report), *summary_lines(report)]:
            print(f"  {line}", file=log)
    if not verdict.ok:
        print(f"davio calibrate: refused: {verdict.message}", file=sys.stderr)
        return EXIT_REFUSED
    return 0
