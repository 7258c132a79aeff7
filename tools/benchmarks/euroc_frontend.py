"""`davio bench euroc-frontend [DIR]`: the MSCKF front-end on real EuRoC images and IMU.

On an EuRoC folder (default: ../shared/data/euroc/V1_01_easy_head, 95 still frames + the full IMU):
KLT tracks per frame (mean / min), tracker milliseconds per frame, and the static initializer's
roll/pitch error (angle between estimated and true 'up' in the IMU frame) in both modes:

- ``jerk`` (OpenVINS EuRoC: still, then an IMU jerk; IMU only, because the head's images end
  before the drone moves);
- ``still`` (initialize once a full window is still; IMU + track disparity).

Ground truth: ``full_sequence_vicon2gt.csv`` (OpenVINS authors' recomputation) and the original
``data.csv`` are both reported when present. The dynamic initializer is fed too and its verdict
(on a still platform it must refuse) is printed.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

NAME = "euroc-frontend"
HELP = "KLT tracks per frame, tracker ms/frame and static-init roll/pitch error on real EuRoC data"

_DEFAULT = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "euroc" / "V1_01_easy_head"
_IMU_AFTER_FRAMES_S = 10.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("path", nargs="?", default=str(_DEFAULT), help="EuRoC sequence folder (or its mav0)")
    p.add_argument("--equalization", default="histogram", choices=("histogram", "clahe", "none"),
                   help="tracker contrast normalisation")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")


def _up_error_deg(gt, t_ns: int, up_est: np.ndarray) -> tuple[float, float]:
    """(angle between estimated and true up in I, |dt| to the closest ground-truth row in s)."""
    from runtime.msckf.init_common import gravity_angle_deg

    k = int(np.argmin(np.abs(gt.t_ns - t_ns)))
    return gravity_angle_deg(up_est, gt.R[k][2, :]), abs(int(gt.t_ns[k]) - t_ns) * 1e-9


def run(args: argparse.Namespace) -> int:
    from drivers import EurocDriver, Frame, ImuSample
    from runtime.errors import DavioError
    from runtime.msckf.init_dynamic import DynamicInitializer
    from runtime.msckf.init_static import StaticInitConfig, StaticInitializer
    from runtime.msckf.tracker import KltTracker, TrackerConfig

    try:
        driver = EurocDriver(args.path)
    except DavioError as exc:
        print(f"euroc-frontend: {exc}")
        return 2
    rig = driver.rig
    tracker = KltTracker(rig.camera, TrackerConfig(equalization=args.equalization))
    jerk = StaticInitializer(StaticInitConfig(wait_for_jerk=True))
    still = StaticInitializer(StaticInitConfig(wait_for_jerk=False))
    T_IC = rig.T_IC if rig.T_IC is not None else np.eye(4)
    offset = float(rig.time_offset_s or 0.0)
    dynamic = DynamicInitializer(rig.camera, T_IC, imu_noise=rig.imu, time_offset_s=offset)
    results: dict[str, object] = {"jerk": None, "still": None}
    counts: list[int] = []
    times_ms: list[float] = []
    last_frame_ns: int | None = None
    dynamic_result = None
    imu_count = 0
    for ev in driver.events():
        if isinstance(ev, ImuSample):
            imu_count += 1
            if last_frame_ns is not None and ev.t_ns > last_frame_ns + 100_000_000:
                # past the images: keep feeding only while a static mode is still undecided
                if all(r is not None for r in results.values()):
                    break
                if ev.t_ns > last_frame_ns + int(_IMU_AFTER_FRAMES_S * 1e9):
                    break
            for name, init in (("jerk", jerk), ("still", still)):
                if results[name] is None:
                    init.feed_imu(ev)
                    if imu_count % 4 == 0:  # try at 50 Hz
                        results[name] = init.try_initialize()
            dynamic.feed_imu(ev)
        elif isinstance(ev, Frame):
            t0 = time.perf_counter()
            tr = tracker.track(ev)
            times_ms.append((time.perf_counter() - t0) * 1e3)
            counts.append(len(tr))
            last_frame_ns = ev.t_ns
            t_imu = ev.t_ns + int(round(offset * 1e9))
            if results["still"] is None:
                still.feed_tracks(t_imu, tr.ids, tr.uv)
            dynamic.feed_tracks(ev.t_ns, tr.ids, tr.uv)
            if dynamic_result is None:
                dynamic_result = dynamic.try_initialize()

    out: dict[str, object] = {
        "sequence": str(args.path),
        "frames": len(counts),
        "tracks_per_frame_mean": float(np.mean(counts)) if counts else 0.0,
        "tracks_per_frame_min": int(np.min(counts)) if counts else 0,
        "tracker_ms_per_frame_mean": float(np.mean(times_ms)) if times_ms else 0.0,
        "tracker_ms_per_frame_median": float(np.median(times_ms)) if times_ms else 0.0,
        "tracker_report": tracker.report(),
        "equalization": args.equalization,
        "dynamic_init": "initialized" if dynamic_result is not None else dynamic.last_reason,
        "dynamic_rejections": dynamic.report()["rejections"],
    }
    mav0 = Path(driver.mav0)
    gts = {}
    for label, fname in (("vicon2gt", "full_sequence_vicon2gt.csv"), ("euroc_gt", "data.csv")):
        if (mav0 / "state_groundtruth_estimate0" / fname).is_file():
            gts[label] = EurocDriver(args.path, groundtruth_file=fname).groundtruth()
    for mode, res in results.items():
        entry: dict[str, object] = {"initialized": res is not None}
        init = jerk if mode == "jerk" else still
        if res is None:
            entry["reason"] = init.last_reason
        else:
            entry["t_ns"] = int(res.t_ns)
            entry["bg"] = [float(x) for x in res.bg]
            entry["ba"] = [float(x) for x in res.ba]
            for label, gt in gts.items():
                if gt is None or len(gt) == 0:
                    continue
                err, dt = _up_error_deg(gt, res.t_ns, res.gravity_in_imu)
                if dt < 0.05:
                    entry[f"roll_pitch_err_deg_{label}"] = err
        out[f"static_{mode}"] = entry
    driver.close()

    if args.json:
        print(json.dumps(out))
        return 0
    print(f"EuRoC front-end on {args.path}")
    print(f"{'frames':<40}{out['frames']}")
    mean, low = out["tracks_per_frame_mean"], out["tracks_per_frame_min"]
    print(f"{'tracks/frame mean | min':<40}{mean:.1f} | {low}")
    print(f"{'tracker ms/frame mean | median':<40}{out['tracker_ms_per_frame_mean']:.2f} | "
          f"{out['tracker_ms_per_frame_median']:.2f}   (2 shared cores: noisy)")
    for mode in ("jerk", "still"):
        e = out[f"static_{mode}"]
        if not e["initialized"]:
            print(f"{'static init (' + mode + ')':<40}not initialized: {e['reason']}")
            continue
        errs = ", ".join(f"{k.removeprefix('roll_pitch_err_deg_')} {v:.3f} deg"
                         for k, v in e.items() if k.startswith("roll_pitch_err_deg_"))
        print(f"{'static init (' + mode + ') roll/pitch err':<40}{errs}")
    print(f"{'dynamic init':<40}{out['dynamic_init']}")
    print(f"{'dynamic init rejections':<40}{out['dynamic_rejections']}")
    return 0
