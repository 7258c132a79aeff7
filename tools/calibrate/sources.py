"""Where `davio calibrate` gets its data: a recording (EuRoC, `davio simulate`, a ROS bag) or a live module
(oak, uvc), with the rig whose intrinsics are used, the model for the bring-up's camera rotations (DA3, the
emulated DA3 on a simulated recording, or none: two-view fits) and the reference extrinsics the report
compares with (never an input)."""

from __future__ import annotations

import argparse
from pathlib import Path

#: the model line of a calibration without a depth model
TWO_VIEW = "none: the bring-up's camera rotations from two-view fits of the tracked features"

LIVE_SOURCES = ("oak", "uvc")


def is_live(source: str) -> bool:
    """SOURCE names a live module (and no file or folder of that name exists here)."""
    return source in LIVE_SOURCES and not Path(source).exists()


def open_live(args: argparse.Namespace, config) -> tuple:
    """(LiveDriver, rig with the intrinsics, model, model description, reference dict) for a live module,
    or a DavioError. The model is a DA3 graph or none (two-view rotations): the emulated DA3 needs a
    simulator's ground truth. The model (before the device opens, where the intrinsics are given) and the
    filter's kernels (under `config`, the run's DavioConfig; the session loads them only when the bring-up
    ends) are loaded before the streams start: the driver is not started, the caller starts it once the
    run is ready to read, and stops it."""
    from runtime.errors import ConfigError
    from tools.calibrate.core import calibration_config
    from tools.commands.live import check_device_args, check_size_against_rig, load_kernels, open_device

    check_device_args(args, "davio calibrate")
    if args.emulated:
        raise ConfigError("--emulated needs a recording written by `davio simulate`; on a live module pass "
                          "--model DA3.onnx, or nothing for two-view rotations of the tracked features")
    given = None
    if args.rig:
        from calib import load_rig

        given = load_rig(args.rig)
        if given.camera is None:
            raise ConfigError(f"{args.rig}: no camera intrinsics")
        check_size_against_rig(args, given)
    model, desc = None, TWO_VIEW
    if args.model and given is not None:   # the model's warm-up before the camera starts (`davio live`)
        from tools.model_open import open_da3

        model, desc = open_da3(args, given.camera, 5)
    # an OAK's factory intrinsics are read from the opened device before its streams start
    driver, rig = open_device(args, given)
    try:
        if given is None and args.model:
            from tools.model_open import open_da3

            model, desc = open_da3(args, rig.camera, 5)
        load_kernels(None, calibration_config(config))   # the rig's extrinsics are withheld: a stand-in's
    except BaseException:
        driver.stop()
        raise
    reference = {"source": None, "T_IC": None, "time_offset_s": None}
    if args.source == "oak" and given is None and rig.T_IC is not None:
        reference.update(source="the OAK's factory calibration", T_IC=rig.T_IC,
                         time_offset_s=rig.time_offset_s)
    return driver, rig, model, desc, reference


def open_inputs(args: argparse.Namespace) -> tuple:
    """(recording, rig with the intrinsics, model, model description, reference dict) or a DavioError."""
    from runtime.errors import ConfigError
    from tools.run_io import open_recording, read_manifest

    given = None
    if args.rig:
        from calib import load_rig

        given = load_rig(args.rig)
    rec = open_recording(
        args.source,
        rebuild=not (args.model or args.two_view),
        policy="strict" if args.strict else "drop",
        rig=given,
        image_topic=args.image_topic,
        imu_topic=args.imu_topic,
    )
    own = rec.driver.rig
    rig = given if given is not None else own
    if rig is None or rig.camera is None:
        where = "no CameraInfo in the bag" if rec.kind == "bag" else "no cam0/sensor.yaml"
        raise ConfigError(
            f"{args.source}: no camera intrinsics ({where}); pass --rig FILE (a Kalibr camchain, "
            "an EuRoC sensor.yaml or folder)"
        )
    if rig.imu is None and own is not None and own.imu is not None:
        rig = rig.replace(imu=own.imu)
    # the recording's own extrinsics (if any) are only a reference for the report, never an input
    reference = {"source": None, "T_IC": None, "time_offset_s": None}
    if own is not None and own.T_IC is not None:
        reference.update(
            source="the recording's own calibration", T_IC=own.T_IC, time_offset_s=own.time_offset_s
        )
    if rec.kind == "simulated":
        cfg = read_manifest(Path(args.source) / "manifest.json").get("config") or {}
        reference.update(
            source="the simulator's rig (manifest.json, sensor.yaml)",
            time_offset_s=float(cfg.get("time_offset_s") or 0.0),
        )
    model, desc = None, TWO_VIEW
    if args.model:
        from tools.model_open import open_da3

        model, desc = open_da3(args, rig.camera, 5)
    elif rec.kind == "simulated" and not args.two_view:
        from models.emulated_da3 import EmulatedDA3

        preset = args.emulated or "base"
        cam = rig.camera
        model = EmulatedDA3(rec.ground_truth_source, cam.K, cam.width, cam.height, preset=preset)
        desc = f"EMULATED DA3 ({preset}) from simulator ground truth -- not a real network"
    elif args.emulated:
        raise ConfigError(
            "--emulated needs a recording written by `davio simulate` (it reads the simulator's "
            "ground truth); for real data pass --model DA3.onnx, or nothing for two-view rotations"
        )
    return rec, rig, model, desc, reference
