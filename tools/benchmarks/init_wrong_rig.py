"""`davio bench init-wrong-rig`: what a wrong rig costs the native start-up, with the dynamic initializer's
rotation check (`dynamic_init.max_rotation_mismatch_fraction`) on and off in the same run.

Each recording runs through the whole pipeline without a depth model (the native initializers armed, as a
run without DA3) three ways: the right rig, the gyroscope logged in deg/s (every gyro sample x 57.3), and
the camera-IMU rotation inverted (T_cam_imu given as T_imu_cam). Per row: the wall time and real-time
factor, tracking ms per frame (median, p90, max: the scheduler's per-frame time, IMU included), poses
published, and the dynamic initializer's refusals by reason. On a wrong rig nothing should publish, and a
robot's pipeline should stay in real time while it says why.

`--sweep`: whether the check ever refuses a right rig. The dynamic initializer alone is fed the KLT tracks
and the IMU of each recording and attempts at every frame, whatever the outcome (the refinement off,
`mle_max_iterations = 0`, which the check precedes; no wait after a refusal, no interval between
checks), so that every window past the parallax check is checked, not only those before a start. Per
recording: windows checked, refused, the largest share of disagreeing keyframe pairs in one window
(refusal above 0.5) and the largest median camera-gyro difference (deg; the bound is 11.5). Recordings:
presets with the IMU errors measured on the real EuRoC IMU, the EuRoC-trajectory simulations of V1_02 and
MH_03 (real IMU), and the real EuRoC V1_01 head (real images), where ../shared is.
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from tools.cli_types import count, number

NAME = "init-wrong-rig"
HELP = "the native start-up's cost on a wrong rig (gyro in deg/s, rotation inverted), rotation check on/off"
DESCRIPTION = __doc__
VARIANTS = ("right", "deg/s", "inverted")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--preset", action="append", default=None,
                   help="motion preset (repeatable; default: euroc, aggressive)")
    p.add_argument("--seconds", type=number, default=15.0, help="recording length, s")
    p.add_argument("--seed", type=count(0), default=4)
    p.add_argument("--sweep", action="store_true",
                   help="instead: the check at every frame of right-rig recordings (false refusals)")
    p.add_argument("--sequence-seconds", type=number, default=60.0,
                   help="--sweep: seconds of each EuRoC-trajectory simulation")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--out", metavar="FILE.json", help="also write the JSON here")


class _Variant:
    """A recording's events and rig as one of VARIANTS (the driver interface run_pipeline reads)."""

    def __init__(self, rec, variant: str) -> None:
        self.rec, self.variant = rec, variant
        rig = rec.rig
        self.rig = rig.replace(T_IC=np.linalg.inv(rig.T_IC)) if variant == "inverted" else rig

    def events(self):
        from runtime.events import ImuSample

        scale = float(np.degrees(1.0)) if self.variant == "deg/s" else 1.0
        for ev in self.rec.events():
            if scale != 1.0 and isinstance(ev, ImuSample):
                ev = ImuSample(ev.t_ns, np.asarray(ev.gyro) * scale, ev.accel)
            yield ev


def measure(rec, variant: str, check: bool) -> dict:
    """One row: run `rec` as `variant` with the rotation check on or off."""
    from runtime.config import DavioConfig
    from tools.run_session import run_pipeline

    cfg = DavioConfig()
    if not check:
        cfg = replace(cfg, dynamic_init=replace(cfg.dynamic_init, max_rotation_mismatch_fraction=1.0))
    t0 = time.perf_counter()
    res = run_pipeline(_Variant(rec, variant), None, cfg, show_progress=False)
    wall = time.perf_counter() - t0
    ms = np.asarray(res.scheduler.per_frame_ms, float)
    rep = res.pipeline.report()
    inits = (rep.get("filter") or {}).get("initializers") or {}
    data_s = float(res.scheduler.sensor_s)
    return {"variant": variant, "rotation_check": check, "wall_s": wall, "data_s": data_s,
            "realtime_factor": data_s / wall if wall > 0 else None, "frames": int(ms.size),
            "ms_median": float(np.median(ms)), "ms_p90": float(np.percentile(ms, 90)),
            "ms_max": float(ms.max()),
            "published": len(res.pipeline.published),
            "published_by": (rep.get("startup") or {}).get("first_published_by"),
            "dynamic_rejections": (inits.get("dynamic") or {}).get("rejections") or {}}


def sweep(rig, events) -> dict:
    """The dynamic initializer's rotation check at every frame of a right rig's `events` (see --sweep)."""
    from runtime.events import ImuSample
    from runtime.msckf.init_dynamic import DynamicInitializer
    from runtime.msckf.init_dynamic_config import DynamicInitConfig
    from runtime.msckf.tracker import KltTracker

    cfg = DynamicInitConfig(mle_max_iterations=0, rotation_mismatch_retry_s=0.0,
                            rotation_check_interval_s=0.0)
    init = DynamicInitializer(rig.camera, rig.T_IC, cfg,
                              imu_noise=rig.imu, time_offset_s=rig.time_offset_s or 0.0)
    tracker = KltTracker(rig.camera)
    frames = 0
    for ev in events:
        if isinstance(ev, ImuSample):
            init.feed_imu(ev)
        else:
            res = tracker.track(ev)
            init.feed_tracks(res.t_ns, res.ids, res.uv)
            init.try_initialize()
            frames += 1
    rep = init.report()
    return {"frames": frames, **rep["rotation_check"], "rejections": rep["rejections"]}


def _sweep_recordings(args: argparse.Namespace) -> list[tuple[str, object]]:
    from drivers.sim import SimConfig, SimRecording
    from tools.benchmarks.mapping import SHARED

    recs: list[tuple[str, object]] = []
    for preset in args.preset or ("euroc", "slow", "handheld", "hover", "rotation", "aggressive"):
        recs.append((f"{preset} (measured IMU)", lambda p=preset: SimRecording.from_preset(
            SimConfig(preset=p, seconds=args.seconds, seed=args.seed, imu_profile="euroc-measured"))))
    for name in ("V1_02_medium", "MH_03_medium"):
        if (SHARED / name).is_dir():
            recs.append((name, lambda n=name: SimRecording.from_euroc_imu_gt(
                SHARED / n, SimConfig(seconds=args.sequence_seconds, seed=args.seed))))
    head = SHARED.parent / "euroc" / "V1_01_easy_head"
    if head.is_dir():
        from drivers.euroc import EurocDriver

        recs.append(("V1_01 head (real images)", lambda: EurocDriver(head)))
    return recs


def _run_sweep(args: argparse.Namespace) -> dict:
    result: dict = {"seconds": args.seconds, "seed": args.seed, "sweep": {}}
    if not args.json:
        print("the dynamic initializer's rotation check at every frame of right rigs "
              "(refused: false refusals)")
        print(f"  {'recording':28s} {'frames':>6s} {'checks':>6s} {'refused':>7s} {'max share':>9s} "
              f"{'max median deg':>14s}")
    for name, make in _sweep_recordings(args):
        rec = make()
        r = sweep(rec.rig, rec.events())
        result["sweep"][name] = r
        if not args.json:
            print(f"  {name:28s} {r['frames']:6d} {r['checks']:6d} {r['refused']:7d} "
                  f"{r['max_disagreeing_share']:9.2f} {r['max_median_deg']:14.2f}", flush=True)
    return result


def run(args: argparse.Namespace) -> int:
    from runtime.json_out import strict_dumps

    result = _run_sweep(args) if args.sweep else _run_rows(args)
    if args.out:
        Path(args.out).write_text(strict_dumps(result, indent=1))
    if args.json:
        print(strict_dumps(result))
    return 0


def _run_rows(args: argparse.Namespace) -> dict:
    from drivers.sim import SimConfig, SimRecording

    result: dict = {"seconds": args.seconds, "seed": args.seed, "rows": {}}
    if not args.json:
        print("native start-up on a right and a wrong rig, no depth model; the dynamic initializer's "
              "rotation check on / off")
        print(f"  {'recording':12s} {'variant':8s} {'check':>5s} {'wall s':>7s} {'x real':>6s} "
              f"{'med ms':>6s} {'p90 ms':>6s} {'max ms':>6s} {'poses':>5s}  dynamic initializer refusals")
    for preset in args.preset or ("euroc", "aggressive"):
        rec = SimRecording.from_preset(SimConfig(preset=preset, seconds=args.seconds, seed=args.seed))
        rows = []
        for variant in VARIANTS:
            for check in (True, False):
                r = measure(rec, variant, check)
                rows.append(r)
                if not args.json:
                    refused = ", ".join(f"{k} {v}" for k, v in sorted(r["dynamic_rejections"].items()))
                    print(f"  {preset:12s} {variant:8s} {'on' if check else 'off':>5s} {r['wall_s']:7.1f} "
                          f"{r['realtime_factor']:6.2f} {r['ms_median']:6.1f} {r['ms_p90']:6.0f} "
                          f"{r['ms_max']:6.0f} {r['published']:5d}  {refused}", flush=True)
        result["rows"][preset] = rows
    return result
