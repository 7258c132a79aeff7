"""`davio bench gyro-scale`: the start-up's gyroscope-scale check (runtime/ffinit/gyro_scale.py) on every
motion preset and on real EuRoC IMU recordings, with the right units and with the gyro logged in deg/s.

Per recording, a start-up window (five images 0.2 s apart) every --every seconds; for each pose-error
factor k (the emulated DA3's unconditioned pose errors = k x `base_upper`; 0.05 is the calibrated `base`,
so 0.05,0.1,0.25,1 are x1, x2, x5, x20) the ratio of the gyro's rate to DA3's over the window (judged when
DA3's rate reaches `ffinit.gyro_scale_min_rate`). Reported: windows judged, the ratio's min / median /
p99 / max with the right units, and how many windows `ffinit.max_gyro_rate_ratio` refuses with the right
units (should be 0) and with the gyro in deg/s (should be all judged).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

NAME = "gyro-scale"
HELP = "the start-up's gyroscope-scale check: rate ratios with the right units and in deg/s"
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


def window_ratios(rec, ks: list[float], every_s: float, seed: int) -> dict[float, dict]:
    """{k: {"ratio": [...] of the judged windows, "ratio_deg_s": [...] the same with the gyro in deg/s}}."""
    from models.emulated_da3 import EmulatedDA3
    from models.emulated_da3.params import make_params, scale_pose_errors
    from runtime.events import Frame
    from runtime.ffinit.config import FFInitConfig
    from runtime.ffinit.gyro_scale import rotation_rates
    from runtime.ffinit.sampling import observations_from_prediction
    from tools.benchmarks.ffinit_accuracy import window_frame_indices

    cfg = FFInitConfig()
    cam, imu, stamps = rec.rig.camera, rec.imu, rec.frame_stamps_ns
    offset = rec.rig.time_offset_s or 0.0
    blank = np.zeros((cam.height, cam.width), np.uint8)
    out: dict[float, dict] = {}
    for k in ks:
        model = EmulatedDA3(rec.gt_source, cam.K, cam.width, cam.height, preset="base", seed=seed)
        model.params = scale_pose_errors(make_params("base_upper"), k)
        ratio, ratio_deg = [], []
        for t0 in range(int(stamps[0]) + 10**8, int(stamps[-1]) - 2 * 10**9, int(every_s * 1e9)):
            idx = window_frame_indices(stamps, t0)
            if idx is None:
                continue
            frames = [Frame(int(stamps[i]), blank) for i in idx]
            obs = observations_from_prediction(model.predict(frames), cfg, K=model.K_rect, seed=seed)
            t_cam = [f.t_ns for f in frames]
            g, d = rotation_rates(t_cam, obs, imu.t_ns, imu.gyro, offset)
            if np.isfinite(g) and d >= cfg.gyro_scale_min_rate:
                ratio.append(g / d)
                ratio_deg.append(rotation_rates(t_cam, obs, imu.t_ns, np.degrees(imu.gyro), offset)[0] / d)
        out[k] = {"ratio": ratio, "ratio_deg_s": ratio_deg}
    return out


def summarise(r: dict, bound: float) -> dict:
    a, b = np.asarray(r["ratio"]), np.asarray(r["ratio_deg_s"])

    def stat(f) -> float | None:
        return float(f(a)) if len(a) else None

    return {"judged": int(len(a)), "min": stat(np.min), "median": stat(np.median),
            "p99": float(np.percentile(a, 99)) if len(a) else None, "max": stat(np.max),
            "refused_right_units": int(np.sum(a > bound)), "refused_deg_s": int(np.sum(b > bound))}


def _recordings(args: argparse.Namespace) -> list[tuple[str, object]]:
    from drivers.sim import SimConfig, SimRecording

    recs: list[tuple[str, object]] = []
    for preset in args.preset or (PRESETS if args.sequence is None else ()):
        recs.append((f"preset {preset}", lambda p=preset: SimRecording.from_preset(
            SimConfig(preset=p, seconds=args.seconds, seed=args.seed))))
    sequences = args.sequence
    if sequences is None and args.preset is None:
        from tools.benchmarks.mapping import SHARED

        sequences = [str(SHARED / s) for s in SEQUENCES if (SHARED / s).is_dir()]
    for s in sequences or ():
        folder = Path(s)
        if not folder.is_dir():
            from tools.benchmarks.mapping import SHARED

            folder = SHARED / s
        if not folder.is_dir():
            raise SystemExit(f"davio bench gyro-scale: no euroc_imu_gt folder {s!r} (needs ../shared/data)")
        recs.append((folder.name, lambda f=folder: SimRecording.from_euroc_imu_gt(
            f, SimConfig(seconds=None, seed=args.seed))))
    return recs


def run(args: argparse.Namespace) -> int:
    from runtime.errors import ConfigError
    from runtime.ffinit.config import FFInitConfig
    from runtime.json_out import strict_dumps

    try:
        ks = [float(x) for x in args.k.split(",") if x.strip()]
    except ValueError as exc:
        raise ConfigError(f"--k expects comma-separated numbers, got {args.k!r}") from exc
    if not ks or not args.every > 0:
        raise ConfigError("--k needs at least one factor and --every must be > 0")
    bound = FFInitConfig().max_gyro_rate_ratio
    result: dict = {"max_gyro_rate_ratio": bound, "k": ks, "every_s": args.every, "recordings": {}}
    if not args.json:
        print(f"gyro rate / DA3 rate per window (refused above {bound:g}); k x base_upper pose errors")
        print(f"  {'recording':24s} {'k':>5s} {'judged':>6s} {'min':>6s} {'median':>6s} {'p99':>6s} "
              f"{'max':>6s} {'refused (rad/s)':>15s} {'refused (deg/s)':>15s}")
    for name, make in _recordings(args):
        rows = window_ratios(make(), ks, args.every, args.seed)
        result["recordings"][name] = {str(k): summarise(r, bound) for k, r in rows.items()}
        if not args.json:
            for k in ks:
                s = result["recordings"][name][str(k)]
                f = (lambda v: "     -" if v is None else f"{v:6.2f}")  # noqa: E731
                print(f"  {name:24s} {k:5.2f} {s['judged']:6d} {f(s['min'])} {f(s['median'])} {f(s['p99'])}"
                      f" {f(s['max'])} {s['refused_right_units']:15d} {s['refused_deg_s']:15d}", flush=True)
    if args.out:
        Path(args.out).write_text(strict_dumps(result, indent=1))
    if args.json:
        print(strict_dumps(result))
    return 0
