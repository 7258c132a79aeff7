"""`davio bench rig-checks`: the start-up's checks of the rig on every motion preset and on real EuRoC IMU
recordings, with the rig right and with the two mistakes they name.

Per recording, a start-up window (five images 0.2 s apart) every --every seconds; for each pose-error
factor k (the emulated DA3's unconditioned pose errors = k x `base_upper`; 0.05 is the calibrated `base`,
so 0.05, 0.1, 0.25, 1 are x1, x2, x5, x20), one DA3 call per window and then:
- gyroscope scale (runtime/ffinit/gyro_scale.py): the ratio of the gyro's rate to DA3's (windows where
  DA3's rate reaches `ffinit.gyro_scale_min_rate`), min / median / p99 / max with the right units, and the
  windows `ffinit.max_gyro_rate_ratio` refuses with the right units (should be 0) and with the gyro logged
  in deg/s (should be every judged one);
- camera-IMU rotation (runtime/ffinit/extrinsics_check.py): the whole window solve with the rig's rotation
  and with it inverted (T_cam_imu given as T_imu_cam); windows refused as `extrinsics_rotation` (with the
  right rotation: false alarms) and the other outcomes.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

NAME = "rig-checks"
HELP = "the start-up's rig checks (gyroscope scale, camera-IMU rotation): right rig against wrong"
DESCRIPTION = __doc__
PRESETS = ("aggressive", "constant-velocity", "euroc", "handheld", "hover", "rotation", "slow")
SEQUENCES = ("V1_02_medium", "MH_03_medium")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--preset", action="append", default=None, choices=PRESETS,
                   help=f"motion preset (repeatable; default: all of {', '.join(PRESETS)})")
    p.add_argument("--sequence", action="append", default=None, metavar="DIR",
                   help="a euroc_imu_gt folder or its name under ../shared/data/euroc_imu_gt (repeatable; "
                        f"default: {', '.join(SEQUENCES)} when ../shared is there)")
    p.add_argument("--seconds", type=float, default=30.0, help="preset recording length, s")
    p.add_argument("--every", type=float, default=0.5, help="a window starts every S seconds")
    p.add_argument("--k", default="0.05,0.1,0.25,1", help="comma-separated pose-error factors on base_upper")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--out", metavar="FILE.json", help="also write the JSON here")


class _Cached:
    """A DepthModel answering every call with one prediction (one DA3 call, several solves)."""

    def __init__(self, model, prediction) -> None:
        self.K_rect, self._prediction = model.K_rect, prediction

    def predict(self, frames):
        return self._prediction


def measure(rec, ks: list[float], every_s: float, seed: int) -> dict[float, dict]:
    """{k: {"ratio", "ratio_deg_s": per judged window, "right", "inverted": {outcome: windows}}}."""
    from models.emulated_da3 import EmulatedDA3
    from models.emulated_da3.params import make_params, scale_pose_errors
    from runtime.events import Frame
    from runtime.ffinit.config import FFInitConfig
    from runtime.ffinit.gyro_scale import rotation_rates
    from runtime.ffinit.initializer import FeedForwardInitializer
    from runtime.ffinit.sampling import observations_from_prediction
    from tools.benchmarks.ffinit_accuracy import window_frame_indices

    cfg = FFInitConfig()
    cam, imu, stamps = rec.rig.camera, rec.imu, rec.frame_stamps_ns
    T_IC = np.asarray(rec.rig.T_IC, float)
    offset = rec.rig.time_offset_s or 0.0
    blank = np.zeros((cam.height, cam.width), np.uint8)
    out: dict[float, dict] = {}
    for k in ks:
        model = EmulatedDA3(rec.gt_source, cam.K, cam.width, cam.height, preset="base", seed=seed)
        model.params = scale_pose_errors(make_params("base_upper"), k)
        row: dict = {"ratio": [], "ratio_deg_s": [], "right": {}, "inverted": {}}
        for t0 in range(int(stamps[0]) + 10**8, int(stamps[-1]) - 2 * 10**9, int(every_s * 1e9)):
            idx = window_frame_indices(stamps, t0)
            if idx is None:
                continue
            frames = [Frame(int(stamps[i]), blank) for i in idx]
            pred = model.predict(frames)
            obs = observations_from_prediction(pred, cfg, K=model.K_rect, seed=seed)
            t_cam = [f.t_ns for f in frames]
            g, d = rotation_rates(t_cam, obs, imu.t_ns, imu.gyro, offset)
            if np.isfinite(g) and d >= cfg.gyro_scale_min_rate:
                row["ratio"].append(g / d)
                g_deg = rotation_rates(t_cam, obs, imu.t_ns, np.degrees(imu.gyro), offset)[0]
                row["ratio_deg_s"].append(g_deg / d)
            for name, R_IC in (("right", T_IC[:3, :3]), ("inverted", T_IC[:3, :3].T)):
                init = FeedForwardInitializer(_Cached(model, pred), R_IC, T_IC[:3, 3], offset, cfg)
                reason = getattr(init.solve(frames, imu.t_ns, imu.gyro, imu.accel), "reason", "accepted")
                row[name][reason] = row[name].get(reason, 0) + 1
        out[k] = row
    return out


def summarise(r: dict, bound: float) -> dict:
    """The table's figures of one recording and k (`measure`'s row)."""
    a, b = np.asarray(r["ratio"]), np.asarray(r["ratio_deg_s"])

    def stat(f) -> float | None:
        return float(f(a)) if len(a) else None

    right, inverted = dict(r.get("right", {})), dict(r.get("inverted", {}))
    return {"judged": int(len(a)), "min": stat(np.min), "median": stat(np.median),
            "p99": float(np.percentile(a, 99)) if len(a) else None, "max": stat(np.max),
            "refused_right_units": int(np.sum(a > bound)), "refused_deg_s": int(np.sum(b > bound)),
            "windows": int(sum(right.values())), "right": right, "inverted": inverted,
            "extrinsics_false_alarms": int(right.get("extrinsics_rotation", 0)),
            "extrinsics_named": int(inverted.get("extrinsics_rotation", 0)),
            "inverted_accepted": int(inverted.get("accepted", 0))}


def _recordings(args: argparse.Namespace) -> list[tuple[str, object]]:
    from drivers.sim import SimConfig, SimRecording
    from tools.benchmarks.mapping import SHARED

    recs: list[tuple[str, object]] = []
    for preset in args.preset or (PRESETS if args.sequence is None else ()):
        recs.append((f"preset {preset}", lambda p=preset: SimRecording.from_preset(
            SimConfig(preset=p, seconds=args.seconds, seed=args.seed))))
    sequences = args.sequence
    if sequences is None and args.preset is None:
        sequences = [s for s in SEQUENCES if (SHARED / s).is_dir()]
    for s in sequences or ():
        folder = Path(s) if Path(s).is_dir() else SHARED / s
        if not folder.is_dir():
            raise SystemExit(f"davio bench rig-checks: no euroc_imu_gt folder {s!r} (needs ../shared/data)")
        recs.append((folder.name, lambda f=folder: SimRecording.from_euroc_imu_gt(
            f, SimConfig(seconds=None, seed=args.seed))))
    return recs


def run(args: argparse.Namespace) -> int:
    from runtime.errors import ConfigError
    from runtime.ffinit.config import FFInitConfig
    from runtime.json_out import strict_dumps
    from tools.benchmarks.ffinit_accuracy import parse_k

    ks = parse_k(args.k)
    if not ks or not args.every > 0:
        raise ConfigError("--k needs at least one factor and --every must be > 0")
    cfg = FFInitConfig()
    bound = cfg.max_gyro_rate_ratio
    result: dict = {"max_gyro_rate_ratio": bound, "extrinsics_check_deg": cfg.extrinsics_check_deg,
                    "extrinsics_check_rms_deg": cfg.extrinsics_check_rms_deg, "k": ks, "every_s": args.every,
                    "recordings": {}}
    if not args.json:
        print(f"per window: gyro rate / DA3 rate (refused above {bound:g}), and the solve with the rig's "
              "rotation right and inverted; k x base_upper pose errors")
        print(f"  {'recording':24s} {'k':>5s} {'judged':>6s} {'min':>6s} {'median':>6s} {'p99':>6s} "
              f"{'max':>6s} {'refused rad/s':>13s} {'refused deg/s':>13s} {'windows':>7s} "
              f"{'extr. false':>11s} {'extr. named (inv.)':>18s} {'inv. accepted':>13s}")
    for name, make in _recordings(args):
        rows = measure(make(), ks, args.every, args.seed)
        result["recordings"][name] = {str(k): summarise(r, bound) for k, r in rows.items()}
        if not args.json:
            for k in ks:
                s = result["recordings"][name][str(k)]
                f = (lambda v: "     -" if v is None else f"{v:6.2f}")  # noqa: E731
                print(f"  {name:24s} {k:5.2f} {s['judged']:6d} {f(s['min'])} {f(s['median'])} {f(s['p99'])}"
                      f" {f(s['max'])} {s['refused_right_units']:13d} {s['refused_deg_s']:13d}"
                      f" {s['windows']:7d} {s['extrinsics_false_alarms']:11d} {s['extrinsics_named']:18d}"
                      f" {s['inverted_accepted']:13d}", flush=True)
    if args.out:
        Path(args.out).write_text(strict_dumps(result, indent=1))
    if args.json:
        print(strict_dumps(result))
    return 0
