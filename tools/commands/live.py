"""`davio live uvc`: run on a live camera-IMU module (a UVC camera and a serial IMU), ROS-free."""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace

from tools.cli_types import count, number, number_in
from tools.model_open import add_gpu_memory_argument

NAME = "live"
HELP = "run live on an OAK (depthai) or a UVC camera + serial IMU; Ctrl-C finishes and writes the run"
DESCRIPTION = (
    "Runs DAVIO on live sensors: an OAK module (depthai 3: a mono camera, or the colour one in grey, and "
    "its IMU on the device clock, mid-exposure stamps, the factory calibration unless --rig), or a UVC "
    "camera read with OpenCV (host monotonic stamps at mid-exposure) "
    "and a serial IMU (Xsens MTData2 or the documented text protocol; device time mapped to the host clock "
    "by an online offset and drift fit). Bounded queues between drivers, tracker and model worker: IMU "
    "samples are never dropped, the oldest waiting image is (counted). A one-line status shows rate, tracks, "
    "state and drops. Ctrl-C or SIGTERM finishes cleanly: trajectories, report and the map archive are "
    "written to --out (run_status.json 'interrupted'). The camera-IMU time offset is refined by the filter."
)


def add_device_arguments(p: argparse.ArgumentParser) -> None:
    """The options that open a live module (`open_device`), shared with `davio calibrate oak|uvc`."""
    p.add_argument("--camera", default="0", help="UVC device index or path (a video file replays it)")
    p.add_argument("--socket", choices=["CAM_B", "CAM_C", "CAM_A"], default="CAM_B",
                   help="OAK camera socket (CAM_B/CAM_C: mono; CAM_A: colour, used in grey)")
    p.add_argument("--imu-rate", type=count(1), default=200, help="OAK IMU rate (Hz)")
    p.add_argument("--imu-calibrated", action="store_true",
                   help="OAK: read the IMU streams corrected with the device's stored affine calibration "
                        "(default: the uncorrected ones; both in the DepthAI IMU frame)")
    p.add_argument("--device-id", default=None, help="OAK device id (default: the first found)")
    p.add_argument("--width", type=count(1), default=None,
                   help="requested image width (px; default: the --rig calibration's, else 640 on an OAK and "
                        "the camera's own on a UVC camera)")
    p.add_argument("--height", type=count(1), default=None,
                   help="requested image height (px; default: the --rig calibration's, else 400 on an OAK)")
    p.add_argument("--fps", type=number, default=None, help="requested camera rate (Hz)")
    p.add_argument("--imu-port", metavar="PORT", help="serial port of the IMU (e.g. /dev/ttyUSB0)")
    p.add_argument("--imu-protocol", choices=["xsens", "text"], default="xsens",
                   help="xsens: Xbus MTData2 (counter, SampleTimeFine, accel, gyro); text: "
                        "$IMU,seq,t_dev_us,ax,ay,az,gx,gy,gz*HH lines")
    p.add_argument("--baud", type=count(50, 16_000_000), default=460800,
                   help="serial baud rate (checked before the model loads)")
    p.add_argument("--imu-stall", type=number_in(0.1, 60.0, unit=" s"), default=5.0, metavar="S",
                   help="a serial IMU sending no valid sample for S seconds, after it streamed, is unplugged "
                        "or stalled and ends the run; a shorter pause is an IMU gap, and one longer than "
                        "msckf.max_imu_outage_s (0.5 s) resets a running filter while the run goes on (raise "
                        "S for a device that pauses longer, e.g. to recalibrate)")


def add_arguments(p: argparse.ArgumentParser) -> None:
    from tools.commands.run import add_prior_map_argument, add_stream_argument
    from tools.live_view import add_view_argument

    p.add_argument("source", choices=["uvc", "oak"], help="the sensor module")
    add_device_arguments(p)
    p.add_argument("--rig", metavar="FILE",
                   help="calibration (Kalibr camchain, EuRoC sensor.yaml or folder); an OAK's factory "
                        "calibration is used without it")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--model", metavar="ONNX", help="DA3 ONNX graph: feed-forward start-up and the map")
    add_gpu_memory_argument(p)
    g.add_argument("--native-only", action="store_true", help="native initializer only, no map")
    p.add_argument("--no-map", action="store_true", help="do not map")
    p.add_argument("--config", metavar="TOML", help="configuration file")
    add_prior_map_argument(p)
    p.add_argument("--seconds", type=number, default=None,
                   help="stop after S seconds of data (> 0), counted from where images and IMU have begun")
    p.add_argument("--out", default="davio_live", help="output folder (new or empty; see --overwrite)")
    p.add_argument("--overwrite", action="store_true", help="replace the previous run in --out")
    p.add_argument("--json", action="store_true", help="print the report as one JSON object at the end")
    add_view_argument(p)
    add_stream_argument(p)


def run(args: argparse.Namespace) -> int:
    from runtime.config import DavioConfig, load_davio_config
    from runtime.errors import ConfigError
    from tools.commands.run import check_run_args, prior_map
    from tools.live_view import open_view
    from tools.run_folder import RunFolder
    from tools.run_outcome import interruptible

    check_run_args(args)
    check_device_args(args, "davio live")
    config = load_davio_config(args.config) if args.config else DavioConfig()
    if args.no_map:
        config = replace(config, mapping=replace(config.mapping, enabled=False))
    folder = RunFolder.prepare(args.out, overwrite=args.overwrite)
    from calib import load_rig

    rig = load_rig(args.rig) if args.rig else None
    if rig is not None and rig.camera is None:
        raise ConfigError(f"{args.rig}: no camera intrinsics")
    check_size_against_rig(args, rig)
    with interruptible():
        # what takes time comes before the streams start (_run starts them once its session is made): a
        # started camera's images would be dropped by its newest-frames buffer until the run reads them,
        # and the start-up would lose them
        view = open_view(args.view)          # viser's import, 0.7 s
        try:
            if rig is not None:
                model, model_desc = _open_model(args, rig, config)    # a DA3 warm-up takes seconds
                prior = prior_map(args, model, config)
                load_kernels(rig, config)
                driver, rig = open_device(args, rig)
            else:   # an OAK's factory calibration: read from the opened device before its streams start
                driver, rig = open_device(args, rig)
                try:
                    model, model_desc = _open_model(args, rig, config)
                    prior = prior_map(args, model, config)
                    load_kernels(rig, config)   # after the model and map load (it limits BLAS to one thread)
                except BaseException:
                    driver.stop()
                    raise
            try:                # the driver stops also when the run folder cannot be made; _run starts it
                folder.create()
                with folder.discard_on_error():
                    return _run(args, folder, driver, rig, model, model_desc, config, prior, view)
            finally:
                driver.stop()
        finally:
            if view is not None:
                view.close()


def _open_model(args: argparse.Namespace, rig, config) -> tuple:
    """(model, description): the DA3 ONNX graph warmed up at the start-up window's shape, or None."""
    if not args.model:
        return None, "none (native initializer only)"
    from tools.model_open import open_da3

    return open_da3(args, rig.camera, config.startup.window_images)


def load_kernels(rig, config) -> float:
    """Load the tracker's and the filter's numba kernels now, before the device starts (a first session
    takes 0.2 s on a 2-core machine, 1 s on a slow one, and a started camera's newest-frames buffer drops
    the images the run has not read). A run's session loads them too, before the streams start, but not
    with a rig whose extrinsics are withheld (a calibration): its filter is made when the bring-up ends,
    mid-run. `rig` None, or one without extrinsics: the EuRoC rig stands in, as the kernels do not
    depend on the camera's values. Returns the seconds it took."""
    from calib import euroc_rig
    from runtime.errors import DavioError
    from runtime.pipeline import VioPipeline

    t0 = time.monotonic()
    if rig is not None and rig.T_IC is not None:
        VioPipeline(rig, None, config)
    else:
        try:
            VioPipeline(euroc_rig(), None, config)
        except DavioError:  # a stand-in the configuration refuses: the session loads the kernels itself
            pass
    return time.monotonic() - t0


def check_device_args(args: argparse.Namespace, command: str) -> None:
    """ConfigError when a UVC source lacks its serial IMU or its intrinsics (before any device opens)."""
    from runtime.errors import ConfigError

    if args.source == "uvc" and not args.imu_port:
        raise ConfigError(f"{command} uvc needs --imu-port (the serial IMU, e.g. /dev/ttyUSB0)")
    if args.source == "uvc" and not args.rig:
        raise ConfigError(f"{command} uvc needs --rig FILE (the camera intrinsics; a Kalibr camchain, an "
                          "EuRoC sensor.yaml or folder)")


def open_device(args: argparse.Namespace, rig):
    """(a LiveDriver for args.source "oak" or "uvc", the rig: `rig`, else an OAK's factory calibration).
    Its streams are not started: an OAK is open (its calibration read), a UVC camera and its serial IMU are
    opened by `driver.start()`. The caller starts it once the run is ready to read (a started camera's
    newest-frames buffer drops the images the run has not read), and stops it."""
    import math

    from runtime.errors import ConfigError

    for opt in ("width", "height", "fps"):
        v = getattr(args, opt, None)
        if v is not None and not (math.isfinite(v) and v > 0):
            raise ConfigError(f"--{opt} must be > 0, got {v!r}")    # 0 would ask for the default unsaid
    if args.source == "oak":
        return _open_oak(args, rig)
    return _open_driver(args, rig), rig


def check_size_against_rig(args: argparse.Namespace, rig) -> None:
    """ConfigError when --width / --height differ from the --rig calibration's image size (the run would
    fail on its first image, after the model's warm-up)."""
    from runtime.errors import ConfigError

    cam = None if rig is None else rig.camera
    if cam is None:
        return
    w, h = args.width or cam.width, args.height or cam.height
    if (w, h) != (cam.width, cam.height):
        raise ConfigError(f"--width/--height ask for {w}x{h} images but the --rig calibration is of "
                          f"{cam.width}x{cam.height} images ({args.rig}): leave them out, or give a "
                          f"calibration of that size")


def describe_device(args: argparse.Namespace) -> str:
    """A one-line description of the live source."""
    return (f"OAK {args.socket}" if args.source == "oak" else
            f"uvc camera {args.camera} + IMU {args.imu_port} ({args.imu_protocol})")


def _open_oak(args: argparse.Namespace, rig):
    """(LiveDriver over an OAK's camera and IMU, the rig: --rig, else the device's factory calibration),
    the device open and its streams not started."""
    from drivers.live import LiveDriver
    from drivers.oak import OakDevice

    cam = None if rig is None else rig.camera      # a --rig's calibration is of its own image size
    dev = OakDevice(socket=args.socket, width=args.width or (cam.width if cam else 640),
                    height=args.height or (cam.height if cam else 400), fps=args.fps or 30.0,
                    imu_rate_hz=args.imu_rate, device_id=args.device_id, imu_calibrated=args.imu_calibrated)
    dev.open()
    try:
        if rig is None:
            rig = dev.rig()
            for note in dev.rig_notes:
                print(f"davio: note: {note}", file=sys.stderr)
        driver = LiveDriver(dev.camera, dev.imu, rig=rig, time_offset_s=rig.time_offset_s or 0.0)
    except BaseException:
        dev.stop()
        raise
    return driver, rig


def _open_driver(args: argparse.Namespace, rig):
    """LiveDriver over a UVC camera (or a video file, paced) and a serial IMU, neither opened yet."""
    from pathlib import Path

    from drivers.live import LiveDriver
    from drivers.serial_imu import SerialImu
    from drivers.uvc import UvcCamera

    device = int(args.camera) if str(args.camera).isdigit() else args.camera
    is_file = not isinstance(device, int) and Path(device).is_file()
    cam = rig.camera
    camera = UvcCamera(device, width=args.width or cam.width, height=args.height or cam.height, fps=args.fps,
                       expected_size=(cam.width, cam.height), realtime=is_file)
    imu = SerialImu(args.imu_port, protocol=args.imu_protocol, baudrate=args.baud,
                    stall_timeout_s=args.imu_stall)
    return LiveDriver(camera, imu, rig=rig, time_offset_s=rig.time_offset_s or 0.0)


def _run(args, folder, driver, rig, model, model_desc: str, config, prior=None, view=None) -> int:
    from runtime.event_window import first_seconds
    from runtime.session import Session
    from tools.run_io import imu_noise_note, rig_summary, write_run
    from tools.run_map import MapOutput
    from tools.run_outcome import conclude, finish_mapping, finishing, judge
    from tools.run_sinks import RunSinks
    from tools.run_summary import summary

    map_out = MapOutput.create(folder.path, rig, model_desc, model, config)
    where = describe_device(args)
    defaulted = config.msckf.defaulted_imu_noise(rig.imu)
    status = _StatusLine(driver)
    sinks = RunSinks(folder.path, None, args.stream, console=status.events, view=view)
    try:
        map_sink = sinks.map_sink(None if map_out is None else map_out.sink)
        session = Session(rig, model, config, map_sink=map_sink, on_pose=sinks.on_pose, prior_map=prior,
                          on_event=sinks.on_event, max_unread_poses=1)     # poses() is never read here
        status.session = session
        driver.start()      # last: the streams start once the run is ready to read them
        print(f"davio live: {where}\n  model: {model_desc}\n"
              + (f"  {imu_noise_note(defaulted)}\n" if defaulted else "")
              + "  Ctrl-C to finish", file=sys.stderr)
        events = driver.events()
        if args.seconds is not None:
            events = first_seconds(events, args.seconds)
        res = session.run_live(events, progress=status, keep_partial=True)
        status.done()
        driver.stop()
        finish_mapping(res, session.pipeline)
        finishing()         # a signal from here on would only lose the outputs
    finally:
        driver.stop()
        sinks.close()
    sinks.warn("davio live")
    judge(res, driver.report())
    map_summary = map_out.finish() if map_out is not None else None
    report = write_run(folder.path, res.pipeline, res.scheduler, None,
                       {"recording": f"live {where}", "model": model_desc, "status": res.status,
                        "status_reason": res.reason, "driver": driver.report(), "map": map_summary,
                        "imu_noise_defaulted": defaulted, **sinks.report(),
                        "rig": rig_summary(rig, str(args.rig) if args.rig
                                           else "the device's factory calibration")},
                       config)
    sinks.journal.close(remove=True)   # the run's own trajectories are written whole
    return conclude(folder, res, report, as_json=args.json, summary=summary)


class _StatusLine:
    """One live line on stderr, refreshed once a second: data time, frame rate, tracks, state, drops; and
    each run event on its own line as it happens (`events`: the session's on_event; the operator has the rig
    in hand). `session` is set once the session exists."""

    def __init__(self, driver) -> None:
        from tools.event_output import EventConsole

        self.session, self.driver = None, driver
        self.last = 0.0
        self.frames0 = 0
        self.tracked0 = (0, 0)     # the pipeline's (tracks_total, frames) at the last line
        self.tty = sys.stderr.isatty()
        self.events = EventConsole(self._say)

    def _say(self, line: str) -> None:
        from tools.stderr_lines import say

        say(("\r\033[K" if self.tty else "") + f"  {line}")

    def __call__(self, sensor_s: float) -> None:
        now = time.monotonic()
        if self.session is None or now - self.last < 1.0:
            return
        pipe = self.session.pipeline
        rep = self.session._scheduler.report if self.session._scheduler is not None else None
        frames = rep.frames if rep is not None else 0
        rate = (frames - self.frames0) / (now - self.last) if self.last else 0.0
        self.last, self.frames0 = now, frames
        st = pipe.startup.report.published_by if pipe.startup is not None else "calibration bring-up"
        # features per frame over the last second, not the run's mean: a covered camera shows at once
        tracked = (pipe.stats.tracks_total, pipe.stats.frames)
        frames_now = tracked[1] - self.tracked0[1]    # none: the camera stalled, not a covered one
        tracks = f"{(tracked[0] - self.tracked0[0]) / frames_now:4.0f}" if frames_now else "   -"
        self.tracked0 = tracked
        drops = rep.frames_dropped if rep is not None else 0
        line = (f"  {sensor_s:7.1f} s  {rate:5.1f} fps  {tracks} tracks  {st or 'starting':<16} "
                f"{len(pipe.published):6d} poses  drops {drops}")
        if pipe.prior is not None:
            seg = pipe.published[len(pipe.published) - 1].segment if len(pipe.published) else 0
            line += f"  prior map: {'localised' if pipe.prior.localized(seg) else 'searching'}"
        from tools.stderr_lines import say

        say(("\r" + line) if self.tty else line, end="" if self.tty else "\n")

    def done(self) -> None:
        if self.tty and self.last:
            from tools.stderr_lines import say

            say("")
