"""`davio demo`: the main job on an embedded default -- simulate a short EuRoC-like recording and run
DAVIO on it end to end with the emulated DA3 (no download, no hardware)."""
from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from tools.cli_types import count, number

NAME = "demo"
HELP = "simulate a short recording and run DAVIO end to end on it (emulated DA3; no download)"
DESCRIPTION = (
    "Simulates a camera-IMU recording in memory (procedural room, EuRoC camera and IMU) that starts in "
    "motion (preset 'handheld': a camera carried at walking pace from the first frame; '--preset euroc' "
    "starts from a standstill) and runs the whole pipeline on it: KLT + MSCKF with the native "
    "initializer armed, and the feed-forward start-up through the buffered-replay handoff using the "
    "EMULATED DA3 (simulator ground truth plus DA3's error modes -- not a real network). Prints which "
    "initializer published first and when, beside the native initializer alone on the same recording, "
    "the trajectory error, and writes the run folder (odometry.tum, report.json, config.toml, plots, "
    "groundtruth.tum) with the dense map the emulated DA3 conditioned on the filter's poses gives (map/ "
    "archive, map.ply; --no-map turns it off)."
)

DEFAULT_PRESET = "handheld"
"""The demo starts in motion: the feed-forward start-up's case (the paper's headline)."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    from drivers.sim.motion import PRESETS
    from models.emulated_da3.params import PRESETS as DA3_PRESETS

    p.add_argument("--out", default="davio_demo",
                   help="output folder (new, empty, or a previous DAVIO run, which is replaced)")
    p.add_argument("--seconds", type=number, default=12.0, help="length of the simulated recording")
    p.add_argument("--preset", default=DEFAULT_PRESET, choices=sorted(PRESETS),
                   help="motion preset (handheld: in motion from the start; euroc: 2 s standstill first; "
                        "constant-velocity, rotation: degenerate starts)")
    p.add_argument("--seed", type=count(0), default=0, help="seed of scene, motion and noise")
    p.add_argument("--da3", default="base", choices=sorted(DA3_PRESETS),
                   help="emulated DA3 preset (models/emulated_da3/PRESETS.md)")
    p.add_argument("--model-latency", type=number, default=0.5, metavar="S",
                   help="simulated DA3 latency in sensor seconds (deterministic replay)")
    p.add_argument("--native-only", action="store_true", help="disable the feed-forward start-up and the map")
    p.add_argument("--no-map", action="store_true", help="do not build the dense map")
    p.add_argument("--no-race", action="store_true",
                   help="skip the native-only replay of the same recording (the comparison line)")
    p.add_argument("--json", action="store_true",
                   help="print the report as one JSON object on stdout (progress goes to stderr)")


def run(args: argparse.Namespace) -> int:
    import sys

    from drivers.sim import SimConfig, SimRecording
    from drivers.sim.recording import check_sim_seconds
    from models.emulated_da3 import EmulatedDA3
    from runtime.config import DavioConfig
    from runtime.errors import ConfigError
    from tools.commands.run import check_run_args
    from tools.evaluation import write_tum
    from tools.event_output import EventFile
    from tools.run_folder import RunFolder
    from tools.run_io import write_run
    from tools.run_map import MapOutput
    from tools.run_outcome import conclude, finishing, interruptible, judge
    from tools.run_session import run_pipeline
    from tools.run_summary import summary

    check_run_args(args)
    check_sim_seconds(args.seconds)
    SimConfig(seed=args.seed)   # a bad seed is refused before the banner
    # the demo is a throwaway: a previous DAVIO run in its folder is replaced, anything else is refused
    try:
        folder = RunFolder.prepare(args.out, overwrite=True)
    except ConfigError as exc:
        raise ConfigError(str(exc).replace("--overwrite only replaces", "the demo only replaces")) from None
    log = sys.stderr if args.json else sys.stdout
    print(f"davio demo: simulating {args.seconds:g} s ({args.preset} motion, seed {args.seed}) and running "
          "DAVIO on it."
          + ("" if args.native_only else "\n  NOTE: the depth model is the EMULATED DA3 (simulator ground "
             "truth + DA3 error modes), not a real network; see README 'Using a real DA3 model'.")
          + ("" if _kernels_cached() else "\n  The first run on this machine compiles the numba kernels "
             "once (about a minute on 2 cores); later runs reuse the cache."), file=log)
    folder.create()
    with folder.discard_on_error(), interruptible():
        rec = SimRecording.from_preset(SimConfig(preset=args.preset, seconds=args.seconds, seed=args.seed))
        if not (args.native_only or args.no_race):
            rec.keep_frames()   # the native-only race replays the frames instead of rendering them again
        cam = rec.rig.camera
        model = None
        if not args.native_only:
            model = EmulatedDA3(rec.gt_source, cam.K, cam.width, cam.height, preset=args.da3, seed=args.seed)
        config = DavioConfig()
        if args.no_map:
            config = replace(config, mapping=replace(config.mapping, enabled=False))
        model_desc = ("none (native only)" if model is None else
                      f"EMULATED DA3 ({args.da3}) -- simulator ground truth, not a real network")
        map_out = MapOutput.create(folder.path, rec.rig, model_desc, model, config)
        event_file = EventFile(folder.path)
        try:
            res = run_pipeline(rec, model, config, model_latency_s=args.model_latency,
                               map_sink=None if map_out is None else map_out.sink, keep_partial=True,
                               on_event=event_file)
        finally:
            event_file.close()
        # a signal from here on would only lose the outputs (the race stops at the native initializer's
        # first pose: seconds)
        finishing("timing the native initializer alone and writing the run's outputs")
        judge(res, None)
        native = None if model is None or args.no_race or res.status != "complete" else \
            _native_only(rec, config, args)
        rec.release_frames()   # the race is over (or skipped): the images need not outlive it
        gt = rec.groundtruth()
        write_tum(folder.path / "groundtruth.tum", gt)   # evo_ape tum groundtruth.tum odometry.tum -a
        report = write_run(folder.path, res.pipeline, res.scheduler, gt,
                           {"recording": f"simulated in memory: preset {args.preset}, {args.seconds:g} s, "
                                         f"seed {args.seed} (ground truth: groundtruth.tum)",
                            "reproduce": _reproduce(args), "native_only": native, "model": model_desc,
                            "status": res.status,
                            "status_reason": res.reason,
                            "map": None if map_out is None else map_out.finish()},
                           config)
        code = conclude(folder, res, report, as_json=args.json, summary=summary)
    st = report["pipeline"].get("startup")
    if st is not None and not args.json:
        print(f"  start-up: {st['ff_requests']} feed-forward windows, {st['ff_accepted']} accepted, "
              f"rejections {st['ff_rejections'] or '{}'}; candidates selected {st['candidates_selected']}")
        if st.get("ff_extensions"):
            print(f"  refused windows re-solved over a longer span (no model call): {st['ff_extensions']}, "
                  f"{st['ff_extension_accepted']} accepted")
        print("  " + _race_line(report))
    return code


def _native_only(rec, config, args: argparse.Namespace) -> dict:
    """The native initializer alone on the same recording: when (and how) it first published. The replay
    stops at that first pose (replays are deterministic: what follows cannot change it)."""
    from runtime.session import Session

    cfg = replace(config, mapping=replace(config.mapping, enabled=False))
    session = Session(rec.rig, None, cfg, on_pose=lambda _pose: session.stop_replay())
    res = session.replay(rec.events())
    st = res.pipeline.startup.report
    t0 = res.scheduler.first_t_ns
    t_f = None if st.first_publish_t_ns is None or t0 is None else (st.first_publish_t_ns - t0) * 1e-9
    return {"T_f_s": t_f, "published_by": st.first_published_by, "seconds": args.seconds,
            "replayed_s": res.scheduler.sensor_s}


def _race_line(report: dict) -> str:
    """Who published first and when, beside the native initializer alone on the same recording."""
    first = report.get("T_f_s")
    who = report.get("first_published_by") or report.get("published_by") or "nobody"
    line = f"start-up race: {who} published first, at {first:.2f} s" if first is not None else \
        "start-up race: nothing was published"
    nat = report.get("native_only")
    if nat is None:
        return line
    if nat["T_f_s"] is None:
        return line + f"; the native initializer alone: no state in {nat['seconds']:g} s"
    return line + f"; the native initializer alone: {nat['T_f_s']:.2f} s ({nat['published_by']})"


def _kernels_cached() -> bool:
    """True when numba's on-disk cache already holds compiled kernels of this installation."""
    import runtime

    root = Path(runtime.__file__).resolve().parent
    return any(root.rglob("*.nbi"))


def _reproduce(args: argparse.Namespace) -> list[str]:
    """Commands that write the demo's recording to disk and run it the same way."""
    mode = "--native-only" if args.native_only else f"--emulated {args.da3}"
    return [f"davio simulate --preset {args.preset} --seconds {float(args.seconds)!r} --seed {args.seed} "
            "--out demo_recording",
            f"davio run demo_recording {mode} --model-latency {float(args.model_latency)!r}"
            + (" --no-map" if args.no_map else "") + " --out demo_rerun"]
