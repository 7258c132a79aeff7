"""`davio bench vio-sim`: the image-based filter on simulated sequences (KLT + MSCKF).

For each sequence (motion presets with a synthetic IMU, or EuRoC-trajectory mode: images rendered
along a real EuRoC ground truth with its real IMU), the filter is initialized from the true state
one second in (as the OpenVINS-simulator benchmark does) and tracks every frame. Reported: ATE after
SE(3) alignment (where the truth stands or turns in place, which fixes no rotation: position + yaw, or the
estimate's spread about its mean; `alignment` says which), time per frame of tracking + filter
(rendering excluded; wall, and the calling thread's CPU, which leaves out OpenCV's worker threads), split
into the tracker and the filter (the filter's frame updates run when the IMU passes the frame, so its IMU
feeding is timed with it), the real-time factor at the camera rate (20 Hz, 752x480): sensor seconds /
processing seconds, the visual measurements the filter accepted, and its resets (each re-initialized from
the true state, so the ATE hides them: read it with the resets).

`--time-offset-error S,...` hands the filter a rig whose camera-IMU time offset is S off the recording's
(positive: the rig says t_imu = t_cam + S more than the truth), and `--calib-time-offset on|off|both`
runs the filter with and without the offset in its state (`msckf.calib_time_offset`).
`--rotation-error DEG,...` hands it a rig whose camera-IMU rotation is DEG off the recording's (about the
camera's optical axis), and `--calib-extrinsics on|off|both` runs it with and without the extrinsics in its
state (`msckf.calib_extrinsics`). Each combination is one row (its images rendered again for each).
"""
from __future__ import annotations

import argparse
import time
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import numpy as np

from runtime.json_out import strict_dumps
from tools.cli_types import count, number

if TYPE_CHECKING:
    from runtime.msckf.config import MsckfConfig

NAME = "vio-sim"
HELP = "KLT + MSCKF on simulated sequences (presets, EuRoC-trajectory mode): ATE, ms/frame, real-time factor"

RENDER_AHEAD_FRAMES = 200
"""Frames rendered before the pipeline sees any of them (about 70 MB at 752x480)."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    from drivers.sim.imu_synth import IMU_PROFILES

    p.add_argument("--preset", action="append", default=None,
                   help="motion preset (repeatable; default: euroc, slow, aggressive)")
    p.add_argument("--preset-imu", default="datasheet", choices=IMU_PROFILES,
                   help="the presets' synthetic IMU errors: the rig's datasheet densities (default), or "
                        "those plus the in-flight errors measured on the real EuRoC IMU")
    p.add_argument("--sequence", action="append", default=None, metavar="DIR",
                   help="euroc_imu_gt folder for EuRoC-trajectory mode (repeatable)")
    p.add_argument("--seconds", type=number, default=30.0, help="length of each sequence")
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--render-ahead", type=count(1), default=RENDER_AHEAD_FRAMES, metavar="FRAMES",
                   help="frames rendered before the timed pipeline sees them (1: each frame just before "
                        "it is tracked, the renderer's cache traffic then lands in the timed frames)")
    p.add_argument("--time-offset-error", default="0", metavar="S[,S...]",
                   help="seconds the rig's camera-IMU time offset is off the recording's, one row each")
    p.add_argument("--calib-time-offset", default="config", choices=("config", "off", "on", "both"),
                   help="estimate the time offset in the filter: as the configuration's default, off, on, "
                        "or a row each")
    p.add_argument("--rotation-error", default="0", metavar="DEG[,DEG...]",
                   help="degrees the rig's camera-IMU rotation is off the recording's (about the camera's "
                        "optical axis), one row each")
    p.add_argument("--calib-extrinsics", default="config", choices=("config", "off", "on", "both"),
                   help="estimate the camera-IMU rotation and lever arm in the filter: as the "
                        "configuration's default, off, on, or a row each")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def _sources(args: argparse.Namespace) -> list[tuple[str, Any]]:
    from drivers.sim import SimConfig, SimRecording

    out = []
    presets = args.preset if args.preset is not None else ([] if args.sequence else ["euroc", "slow",
                                                                                    "aggressive"])
    for name in presets:
        out.append((f"preset {name}", lambda n=name: SimRecording.from_preset(
            SimConfig(preset=n, seconds=args.seconds, seed=args.seed, imu_profile=args.preset_imu))))
    for seq in args.sequence or []:
        out.append((f"euroc-trajectory {seq.rstrip('/').split('/')[-1]}",
                    lambda s=seq: SimRecording.from_euroc_imu_gt(s, SimConfig(seconds=args.seconds,
                                                                               seed=args.seed))))
    return out


def _true_state(gt: Any, t_ns: int) -> tuple:
    """(R, p, v, bg, ba) of the ground truth at t_ns; velocity by central differences (10 ms) and
    zero biases when the ground truth lacks them (TUM files)."""
    from runtime.geometry import interpolate_poses

    g = interpolate_poses(gt, np.array([t_ns]))
    if g.v is not None:
        v = g.v[0]
    else:
        pm = interpolate_poses(gt, np.array([t_ns - 5_000_000, t_ns + 5_000_000])).p
        v = (pm[1] - pm[0]) / 0.01
    zero = np.zeros(3)
    return (g.R[0], g.p[0], v, zero if g.bg is None else g.bg[0], zero if g.ba is None else g.ba[0])


def _rendered_ahead(events: Iterator[Any], frames: int = RENDER_AHEAD_FRAMES) -> Iterator[Any]:
    """The recording's events, rendered `frames` camera frames at a time before they are handed on.

    Rendering a frame between two timed frames (the renderer's parallel kernels, its few hundred MB of
    scene and image traffic) leaves caches and cores cold for the tracker and the filter, which a camera
    never does: measured on the euroc preset, 0.4-1 ms per frame of the pipeline's time (BENCHMARKS.md)."""
    batch: list = []
    n = 0
    for ev in events:
        batch.append(ev)
        if hasattr(ev, "image"):
            n += 1
            if n == frames:
                yield from batch
                batch, n = [], 0
    yield from batch


def run_one(rec: Any, init_after_s: float = 1.0, render_ahead: int = RENDER_AHEAD_FRAMES,
            msckf: MsckfConfig | None = None, time_offset_error_s: float = 0.0,
            rotation_error_deg: float = 0.0) -> dict:
    """Track one recording from a ground-truth initial state; returns the figures.

    msckf: the filter's MsckfConfig (default: MsckfConfig()); the rig's IMU noise is applied to it.
    time_offset_error_s: the filter's camera-IMU time offset is the rig's plus this (a wrong rig).
    rotation_error_deg: the filter's camera-IMU rotation is the rig's turned this far about the camera's
        optical axis (a wrong rig)."""
    from runtime.geometry import PoseTrajectory
    from runtime.msckf.config import MsckfConfig
    from runtime.msckf.estimator import MsckfEstimator
    from runtime.msckf.tracker import KltTracker
    from tools.evaluation import ate, ate_degenerate_truth, truth_is_degenerate

    rig = rec.rig
    given = rig
    if rotation_error_deg:
        from dataclasses import replace

        from scipy.spatial.transform import Rotation

        T_IC = np.array(rig.T_IC, np.float64)
        T_IC[:3, :3] = T_IC[:3, :3] @ Rotation.from_euler("z", rotation_error_deg, degrees=True).as_matrix()
        given = replace(rig, T_IC=T_IC)
    est = MsckfEstimator(given, (msckf or MsckfConfig()).with_imu_noise(rig.imu))
    if time_offset_error_s:
        est.set_time_offset(est.time_offset_s + time_offset_error_s)
    tracker = KltTracker(rig.camera)
    gt = rec.groundtruth()
    t_init = int(rec.imu.t_ns[0]) + int(init_after_s * 1e9)
    states, frames = [], 0
    # wall and thread-CPU seconds of the tracker and of the filter: the filter works when the IMU passes a
    # frame (feed_imu propagates and runs the frame's updates), so feed_imu is timed with it
    wall = {"tracker": 0.0, "filter": 0.0}
    cpu = {"tracker": 0.0, "filter": 0.0}
    for ev in _rendered_ahead(rec.events(), render_ahead):
        w0, c0 = time.perf_counter(), time.thread_time()
        if not hasattr(ev, "image"):
            states += est.feed_imu(ev)
            wall["filter"] += time.perf_counter() - w0
            cpu["filter"] += time.thread_time() - c0
            continue
        res = tracker.track(ev)
        w1, c1 = time.perf_counter(), time.thread_time()
        if not est.initialized and ev.t_ns >= t_init:
            est.initialize_from_state(int(ev.t_ns) - 1, *_true_state(gt, int(ev.t_ns)), source="groundtruth")
        states += est.feed_tracks(int(ev.t_ns), res.ids, res.uv)
        w2, c2 = time.perf_counter(), time.thread_time()
        wall["tracker"] += w1 - w0
        cpu["tracker"] += c1 - c0
        wall["filter"] += w2 - w1
        cpu["filter"] += c2 - c1
        frames += 1
    w0, c0 = time.perf_counter(), time.thread_time()
    states += est.flush()
    wall["filter"] += time.perf_counter() - w0
    cpu["filter"] += time.thread_time() - c0
    n = max(frames, 1)
    report = est.report()
    out: dict = {"frames": frames, "states": len(states),
                 "ms_per_frame_wall": 1e3 * (wall["tracker"] + wall["filter"]) / n,
                 "ms_per_frame_cpu": 1e3 * (cpu["tracker"] + cpu["filter"]) / n,
                 "tracker_ms_per_frame_wall": 1e3 * wall["tracker"] / n,
                 "filter_ms_per_frame_wall": 1e3 * wall["filter"] / n,
                 # the estimator's own timer around its frame updates: contained in the filter's share
                 "filter_updates_ms_per_frame_wall": 1e3 * est.counters.time_frame_s / n,
                 # a reset re-initializes from the true state here: each is a divergence the ATE hides
                 "resets": report["divergence_resets"],
                 "reset_reasons": list(report["divergence_reasons"]),
                 # visual measurements the filter accepted: MSCKF features and SLAM landmark observations
                 "msckf_features_used": report["msckf_features_used"],
                 "slam_updates": report["slam_updates"],
                 "time_offset_error_s": time_offset_error_s,
                 "rotation_error_deg": rotation_error_deg,
                 "time_offset_end_error_s": est.time_offset_s - float(rig.time_offset_s or 0.0)}
    wall_total = wall["tracker"] + wall["filter"]
    sensor_s = (rec.frame_stamps_ns[-1] - rec.frame_stamps_ns[0]) * 1e-9
    out["realtime_factor"] = sensor_s / wall_total if wall_total > 0 else None
    if len(states) >= 3:
        traj = PoseTrajectory([s.t_ns for s in states], [s.p_OI for s in states], [s.R_OI for s in states])
        if truth_is_degenerate(traj, gt):   # the truth stands or turns in place: no rotation to fit
            r, out["alignment"] = ate_degenerate_truth(traj, gt), "degenerate truth"
        else:
            r, out["alignment"] = ate(traj, gt, align_method="se3"), "se3"
        if r is not None:   # None: no estimate inside the truth's span
            out["ate_se3_m"] = float(r.trans["rmse"])
            rot = getattr(r, "rot", None)
            out["ate_rot_deg"] = float(rot["rmse"]) if rot is not None else None
        out["path_m"] = float(gt.path_length())
    return out


def _number_list(text: str, bound: float) -> list[float] | None:
    """The distinct numbers of a comma-separated list, each finite and within +-bound; None otherwise."""
    try:
        values = list(dict.fromkeys(float(x) for x in text.split(",") if x.strip()))
    except ValueError:
        return None
    return values if values and all(np.isfinite(v) and abs(v) <= bound for v in values) else None


def run(args: argparse.Namespace) -> int:
    from runtime.msckf.config import MsckfConfig

    errors = _number_list(args.time_offset_error, 0.5)
    if errors is None:
        print(f"vio-sim: --time-offset-error must be seconds within +-0.5, got {args.time_offset_error!r}")
        return 2
    rot_errors = _number_list(args.rotation_error, 45.0)
    if rot_errors is None:
        print(f"vio-sim: --rotation-error must be degrees within +-45, got {args.rotation_error!r}")
        return 2
    which = {"config": [None], "off": [False], "on": [True], "both": [False, True]}
    calib, calib_x = which[args.calib_time_offset], which[args.calib_extrinsics]
    plain = len(calib) == 1 and errors == [0.0] and len(calib_x) == 1 and rot_errors == [0.0]
    results = {}
    for name, make in _sources(args):
        rec = make()
        for on, on_x, err, rot in ((a, b, c, d) for a in calib for b in calib_x for c in errors
                                   for d in rot_errors):
            flags = {k: v for k, v in (("calib_time_offset", on), ("calib_extrinsics", on_x))
                     if v is not None}
            cfg = MsckfConfig(**flags)
            dt = "in state" if cfg.calib_time_offset else "fixed"
            row = name if plain else (f"{name}, rig offset {1e3 * err:+.0f} ms, dt {dt}"
                                      + (f", rig rotation {rot:+g} deg, extrinsics "
                                         f"{'in state' if cfg.calib_extrinsics else 'fixed'}"
                                         if len(calib_x) > 1 or rot_errors != [0.0] else ""))
            results[row] = r = run_one(rec, render_ahead=args.render_ahead, msckf=cfg,
                                       time_offset_error_s=err, rotation_error_deg=rot)
            if not args.json:
                print(f"  {row:32s} ATE {r.get('ate_se3_m', float('nan')):.3f} m  resets {r['resets']}  "
                      f"dt off by {1e3 * r['time_offset_end_error_s']:+.1f} ms at the end  "
                      f"{r['ms_per_frame_wall']:.1f} ms/frame", flush=True)
    if args.json:
        print(strict_dumps(results))
        return 0
    from rich.console import Console
    from rich.table import Table

    t = Table(title="KLT + MSCKF on simulated sequences (GT init; rendering excluded)")
    for c in ("sequence", "ATE se3 (m)", "rot (deg)", "path (m)", "ms/frame wall", "tracker", "filter",
              "ms/frame CPU", "real-time factor", "resets"):
        t.add_column(c)
    nan = float("nan")
    for name, r in results.items():
        rot = r.get("ate_rot_deg")
        t.add_row(name, f"{r.get('ate_se3_m', nan):.3f}", "-" if rot is None else f"{rot:.2f}",
                  f"{r.get('path_m', nan):.1f}", f"{r['ms_per_frame_wall']:.1f}",
                  f"{r['tracker_ms_per_frame_wall']:.1f}", f"{r['filter_ms_per_frame_wall']:.1f}",
                  f"{r['ms_per_frame_cpu']:.1f}", f"{r['realtime_factor'] or 0:.1f}", str(r["resets"]))
    Console().print(t)
    return 0
