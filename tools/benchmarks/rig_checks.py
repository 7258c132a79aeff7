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
  right rotation: false alarms) and the other outcomes;
- camera-IMU time offset (runtime/ffinit/time_offset_check.py): the whole window solve with the rig's offset
  off by each --time-offset-error (s; positive: the camera's stamps run late); windows solved at an offset
  the check found (with its distance from the truth; |log s| of every accepted window) or refused as
  `time_offset`, and, from the right rig's solves, findings where there is nothing to find (false alarms).
Every solve gets the IMU as the start-up hands it over (0.22 s before the window's first image to 20 ms
past its last, at the offset in use): a camera stamped early (a negative error) is then found from the
window's first three pairs but not solved at the offset found, which needs IMU past the window; live, the
start-up adopts it and solves the windows after it there.
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from tools.cli_types import count, number, number_in

NAME = "rig-checks"
HELP = "the start-up's rig checks (gyroscope scale, camera-IMU rotation): right rig against wrong"
DESCRIPTION = __doc__
PRESETS = ("aggressive", "constant-velocity", "euroc", "handheld", "hover", "rotation", "slow")
SEQUENCES = ("V1_02_medium", "MH_03_medium")


def add_recording_arguments(p: argparse.ArgumentParser, seconds: float) -> None:
    """--preset, --sequence and --seconds (the recordings `_recordings` builds)."""
    p.add_argument("--preset", action="append", default=None, choices=PRESETS,
                   help=f"motion preset (repeatable; default: all of {', '.join(PRESETS)})")
    p.add_argument("--sequence", action="append", default=None, metavar="DIR",
                   help="a euroc_imu_gt folder or its name under ../shared/data/euroc_imu_gt (repeatable; "
                        f"default: {', '.join(SEQUENCES)} when ../shared is there)")
    p.add_argument("--seconds", type=number, default=seconds, help="preset recording length, s")


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_recording_arguments(p, 30.0)
    p.add_argument("--every", type=number_in(0.01, 3600, unit=" s"), default=0.5,
                   help="a window starts every S seconds")
    p.add_argument("--k", default="0.05,0.1,0.25,1", help="comma-separated pose-error factors on base_upper")
    p.add_argument("--time-offset-error", default="-0.05,0.05", metavar="S,...",
                   help="comma-separated errors of the rig's camera-IMU time offset, s")
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--out", metavar="FILE.json", help="also write the JSON here")


def _handed_over(imu, t_cam: list[int], offset_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t_ns, gyro, accel) of the IMU samples the start-up hands a window's solve (runtime.startup)."""
    off = int(round(offset_s * 1e9))
    from runtime.ffinit.config import FFInitConfig
    from runtime.ffinit.time_offset_check import imu_lead_s

    lead_ns = int(round(imu_lead_s(FFInitConfig()) * 1e9))
    keep = (imu.t_ns >= t_cam[0] + off - lead_ns) & (imu.t_ns <= t_cam[-1] + off + 20_000_000)
    return imu.t_ns[keep], imu.gyro[keep], imu.accel[keep]


class _Cached:
    """A DepthModel answering every call with one prediction (one DA3 call, several solves)."""

    def __init__(self, model, prediction) -> None:
        self.K_rect, self._prediction = model.K_rect, prediction

    def predict(self, frames):
        return self._prediction


def _outcome(res: Any, model: Any) -> tuple[str, dict]:
    """(the solve's outcome: "accepted", "accepted_at_found_offset" or the rejection reason, and the figures
    of an offset finding: its offset and the accepted state's |log s|)."""
    from runtime.msckf.init_common import InitResult

    if not isinstance(res, InitResult):
        found = getattr(res, "time_offset_s", None)
        return res.reason, ({} if found is None else {"offset": found})
    log_s = abs(float(np.log(res.info["scale"] * model.last_diagnostics["global_scale"])))
    if "time_offset_s" in res.info:
        return "accepted_at_found_offset", {"offset": res.info["time_offset_s"], "log_s": log_s}
    return "accepted", {"log_s": log_s}


def measure(rec, ks: list[float], every_s: float, seed: int,
            offset_errors: tuple[float, ...] = ()) -> dict[float, dict]:
    """{k: {"ratio", "ratio_deg_s": per judged window, "right", "inverted", "offset <e>": {outcome: windows},
    "offset_found_err_ms <e>": per finding, "log_s <outcome>": per accepted window}}."""
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
        row: dict = {"ratio": [], "ratio_deg_s": [], "right": {}, "inverted": {}, "right_findings": 0}
        for e in offset_errors:
            row[f"offset {e:g}"], row[f"offset_found_err_ms {e:g}"], row[f"log_s {e:g}"] = {}, [], []
        row["log_s right"] = []
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
            cached = _Cached(model, pred)
            for name, R_IC, off in (("right", T_IC[:3, :3], offset), ("inverted", T_IC[:3, :3].T, offset),
                                    *((f"offset {e:g}", T_IC[:3, :3], offset + e) for e in offset_errors)):
                init = FeedForwardInitializer(cached, R_IC, T_IC[:3, 3], off, cfg)
                outcome, fig = _outcome(init.solve(frames, *_handed_over(imu, t_cam, off)), model)
                row[name][outcome] = row[name].get(outcome, 0) + 1
                if name == "right":
                    row["right_findings"] += int("offset" in fig)
                    if "log_s" in fig:
                        row["log_s right"].append(fig["log_s"])
                elif name.startswith("offset "):
                    if "offset" in fig:
                        row[f"offset_found_err_ms {name[7:]}"].append((fig["offset"] - offset) * 1e3)
                    if "log_s" in fig:
                        row[f"log_s {name[7:]}"].append(fig["log_s"])
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
            "inverted_accepted": int(inverted.get("accepted", 0)),
            "time_offset": _offset_summary(r)}


def _offset_summary(r: dict) -> dict:
    """The time-offset figures of `measure`'s row: false findings with the right rig, and per offset error
    the outcomes, how far the found offsets are from the truth (ms) and the accepted scales' |log s|."""
    def stat(v: list, f) -> float | None:
        return float(f(np.asarray(v))) if len(v) else None

    out: dict = {"false_findings": int(r.get("right_findings", 0)),
                 "right_log_s_median": stat(r.get("log_s right", []), np.median),
                 "right_log_s_max": stat(r.get("log_s right", []), np.max), "errors": {}}
    for key in [k for k in r if k.startswith("offset ")]:
        e = key[7:]
        outcomes, err, log_s = dict(r[key]), r[f"offset_found_err_ms {e}"], r[f"log_s {e}"]
        out["errors"][e] = {"outcomes": outcomes, "solved": int(outcomes.get("accepted_at_found_offset", 0)),
                            "named": int(outcomes.get("time_offset", 0)),
                            "found_err_ms_median": stat(np.abs(err), np.median) if err else None,
                            "found_err_ms_max": stat(np.abs(err), np.max) if err else None,
                            "log_s_median": stat(log_s, np.median), "log_s_max": stat(log_s, np.max)}
    return out


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


def _print_offsets(result: dict, ks: list[float]) -> None:
    """The time-offset table: per recording, k and offset error."""
    f = (lambda v, d=3: "     -" if v is None else f"{v:6.{d}f}")  # noqa: E731
    print("camera-IMU time offset: the rig's off by each error; windows solved at the offset found, named "
          "(refused as time_offset), |found - truth| ms, |log s| of the accepted windows (the right rig's "
          "beside)")
    print(f"  {'recording':24s} {'k':>5s} {'error ms':>8s} {'windows':>7s} {'solved':>6s} {'named':>5s} "
          f"{'|err| med':>9s} {'|err| max':>9s} {'log s med':>9s} {'log s max':>9s} {'right med':>9s} "
          f"{'right max':>9s} {'false':>5s}")
    for name, per_k in result["recordings"].items():
        for k in ks:
            s = per_k[str(k)]
            t = s["time_offset"]
            for e, row in t["errors"].items():
                print(f"  {name:24s} {k:5.2f} {float(e) * 1e3:+8.0f} {s['windows']:7d} {row['solved']:6d} "
                      f"{row['named']:5d}    {f(row['found_err_ms_median'], 1)}"
                      f"    {f(row['found_err_ms_max'], 1)}"
                      f"    {f(row['log_s_median'])}    {f(row['log_s_max'])}    {f(t['right_log_s_median'])}"
                      f"    {f(t['right_log_s_max'])} {t['false_findings']:5d}")


def run(args: argparse.Namespace) -> int:
    from runtime.errors import ConfigError
    from runtime.ffinit.config import FFInitConfig
    from runtime.json_out import strict_dumps
    from tools.benchmarks.ffinit_accuracy import parse_k

    ks = parse_k(args.k)
    if not ks or not args.every > 0:
        raise ConfigError("--k needs at least one factor and --every must be > 0")
    offset_errors = tuple(parse_k(args.time_offset_error, "--time-offset-error"))
    if any(not abs(e) < 1.0 for e in offset_errors):
        raise ConfigError(f"--time-offset-error expects errors below 1 s in size, got "
                          f"{args.time_offset_error!r}")
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
        rows = measure(make(), ks, args.every, args.seed, offset_errors)
        result["recordings"][name] = {str(k): summarise(r, bound) for k, r in rows.items()}
        if not args.json:
            for k in ks:
                s = result["recordings"][name][str(k)]
                f = (lambda v: "     -" if v is None else f"{v:6.2f}")  # noqa: E731
                print(f"  {name:24s} {k:5.2f} {s['judged']:6d} {f(s['min'])} {f(s['median'])} {f(s['p99'])}"
                      f" {f(s['max'])} {s['refused_right_units']:13d} {s['refused_deg_s']:13d}"
                      f" {s['windows']:7d} {s['extrinsics_false_alarms']:11d} {s['extrinsics_named']:18d}"
                      f" {s['inverted_accepted']:13d}", flush=True)
    if not args.json and offset_errors:
        _print_offsets(result, ks)
    if args.out:
        Path(args.out).write_text(strict_dumps(result, indent=1))
    if args.json:
        print(strict_dumps(result))
    return 0
