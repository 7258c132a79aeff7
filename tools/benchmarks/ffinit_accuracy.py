"""`davio bench ffinit-accuracy`: the feed-forward initializer alone vs the emulated DA3's pose errors.

Calibrates the emulator's unconditioned pose errors (models/emulated_da3/PRESETS.md) against the
paper's end-to-end start-up accuracy. Over many 5-image windows (images 0.2 s apart, one window
every `--every` s) of simulated recordings (EuRoC-trajectory mode: images rendered along the real
ground truth with the real IMU), the initializer solves each window once per pose-error factor k:
the reference preset's rotation, translation-direction, translation-length and centre-floor errors
are all multiplied by k (`models.emulated_da3.params.scale_pose_errors`), with the same random
draws for every k (common random numbers), so the rows differ only by k. Reported per k: accepted
windows, and over the accepted ones the median velocity error (IMU frame, m/s: yaw-free), gravity-
direction error (deg), |log scale error| and the share of "wrong-scale" windows (|log s err| > 0.1).
The frames' pixels are not rendered (the emulated DA3 reads the ground truth at their stamps).
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from runtime.json_out import strict_dumps
from tools.cli_types import count, number, number_in, number_or_inf
from tools.evaluation.state_errors import gt_velocity, state_errors

NAME = "ffinit-accuracy"
HELP = "feed-forward initializer alone: accepted windows and velocity/gravity/scale errors vs DA3 pose errors"

WRONG_SCALE_LOG = 0.1
"""|log(s / s_true)| above which an accepted window counts as wrong-scale."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sequence", action="append", default=None, metavar="DIR",
                   help="euroc_imu_gt folder (repeatable); default: --preset")
    p.add_argument("--preset", default="euroc", help="motion preset when no --sequence is given")
    p.add_argument("--seconds", type=number, default=60.0, help="preset recording length, s")
    p.add_argument("--every", type=number_in(0.01, 3600, unit=" s"), default=2.0,
                   help="a window starts every S seconds")
    p.add_argument("--max-windows", type=count(1), default=None,
                   help="at most this many windows per recording")
    p.add_argument("--k", default="0,0.25,0.5,0.75,1", help="comma-separated pose-error factors")
    p.add_argument("--reference", default="base_upper", help="emulated-DA3 preset that k scales")
    p.add_argument("--fields", default=None,
                   help="comma-separated pose-error knobs that k scales (default: all of POSE_ERROR_FIELDS;"
                        " the others are set to 0) -- to see which knob drives the errors")
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--sim-accel-bias-sigma", type=number, default=None, metavar="S",
                   help="presets: the simulated IMU's initial accelerometer-bias sigma, m/s^2 (default 0.05;"
                        " 0 shows what the bias alone does to the scale)")
    p.add_argument("--config", metavar="TOML", help="a run configuration whose [ffinit] table is used")
    p.add_argument("--max-scale-uncertainty", type=number_or_inf, default=None, metavar="U",
                   help="the scale-observability gate's bound (default: FFInitConfig's; inf = gate off)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--out", metavar="FILE", help="also write the JSON (with per-window rows) here")


def window_frame_indices(stamps_ns: np.ndarray, t0_ns: int, n: int = 5, spacing_s: float = 0.2,
                         tol_s: float = 0.03) -> list[int] | None:
    """Indices of the n frames nearest t0 + j * spacing (None if one is farther than tol)."""
    from runtime.startup_buffer import nearest_stamps

    return nearest_stamps(stamps_ns, [t0_ns + int(round(j * spacing_s * 1e9)) for j in range(n)], tol_s)


def window_excitation(t_ns: np.ndarray, gyro: np.ndarray, accel: np.ndarray, t0_ns: int,
                      t1_ns: int) -> dict:
    """What the IMU saw over a window (for looking for an excitation gate): the RMS deviation of the
    specific force from its window mean (m/s^2) and the RMS gyro rate (deg/s)."""
    m = (t_ns >= t0_ns) & (t_ns <= t1_ns)
    if m.sum() < 3:
        return {"accel_dev_rms": None, "gyro_rms_dps": None}
    a = accel[m]
    return {"accel_dev_rms": float(np.sqrt(np.mean(np.sum((a - a.mean(axis=0)) ** 2, axis=1)))),
            "gyro_rms_dps": float(np.degrees(np.sqrt(np.mean(np.sum(gyro[m] ** 2, axis=1)))))}


def summarise(rows: list[dict]) -> dict:
    """Accepted count and medians over accepted windows (None where none was accepted)."""
    acc = [r for r in rows if r["accepted"]]

    def med(key: str) -> float | None:
        return float(np.median([r[key] for r in acc])) if acc else None

    p90 = float(np.percentile([r["velocity_err"] for r in acc], 90)) if acc else None
    return {"windows": len(rows), "accepted": len(acc), "velocity_err_median": med("velocity_err"),
            "gravity_err_deg_median": med("gravity_err_deg"),
            "abs_log_scale_err_median": med("abs_log_scale_err"), "velocity_err_p90": p90,
            "wrong_scale": int(sum(r["abs_log_scale_err"] > WRONG_SCALE_LOG for r in acc))}


def _recordings(args: argparse.Namespace) -> list[tuple[str, Any]]:
    from drivers.sim import SimConfig, SimRecording
    from runtime.errors import ConfigError

    if args.sequence:
        if args.sim_accel_bias_sigma is not None:
            raise ConfigError("--sim-accel-bias-sigma applies to presets (a sequence replays its real IMU)")
        cfg = SimConfig(seconds=None, seed=args.seed)
        return [(Path(s).name, lambda s=s: SimRecording.from_euroc_imu_gt(s, cfg)) for s in args.sequence]
    imu_errors = None
    if args.sim_accel_bias_sigma is not None:
        from dataclasses import replace

        from drivers.sim.imu_synth import ImuErrorModel

        imu_errors = replace(ImuErrorModel(), initial_ba_sigma=args.sim_accel_bias_sigma)
    return [(f"preset {args.preset}", lambda: SimRecording.from_preset(
        SimConfig(preset=args.preset, seconds=args.seconds, seed=args.seed, imu_errors=imu_errors)))]


def measure_recording(rec: Any, ks: list[float], reference: str, every_s: float, seed: int,
                      max_windows: int | None = None, fields: list[str] | None = None,
                      ff_config: Any = None) -> dict[float, list[dict]]:
    """Per k, one row per window of `rec` (accepted or the rejection reason, and the errors).

    fields: the pose-error knobs k scales (None: all); the other knobs are set to zero.
    ff_config: the FFInitConfig of the initializer (None: defaults).
    """
    from dataclasses import replace

    from models.emulated_da3 import EmulatedDA3
    from models.emulated_da3.params import POSE_ERROR_FIELDS, make_params, scale_pose_errors
    from runtime.events import Frame
    from runtime.ffinit.initializer import FeedForwardInitializer
    from runtime.geometry import interpolate_poses
    from runtime.msckf.init_common import InitResult

    gt = rec.groundtruth()
    cam = rec.rig.camera
    T_IC = np.asarray(rec.rig.T_IC, float)
    off_ns = int(round((rec.rig.time_offset_s or 0.0) * 1e9))
    stamps = rec.frame_stamps_ns
    imu = rec.imu
    ref = make_params(reference)
    if fields is not None:
        ref = replace(ref, **{f: 0.0 for f in POSE_ERROR_FIELDS if f not in fields})
    params = {k: scale_pose_errors(ref, k) for k in ks}
    blank = np.zeros((cam.height, cam.width), np.uint8)
    t_lo = max(int(stamps[0]), int(imu.t_ns[0]) - off_ns, int(gt.t_ns[0]) - off_ns) + 100_000_000
    t_hi = min(int(stamps[-1]), int(imu.t_ns[-1]) - off_ns, int(gt.t_ns[-1]) - off_ns) - 1_000_000_000
    rows: dict[float, list[dict]] = {k: [] for k in ks}
    w = 0
    for t0 in range(t_lo, t_hi, int(every_s * 1e9)):
        if max_windows is not None and w >= max_windows:
            break
        idx = window_frame_indices(stamps, t0)
        if idx is None:
            continue
        frames = [Frame(int(stamps[i]), blank) for i in idx]
        excitation = window_excitation(imu.t_ns, imu.gyro, imu.accel, int(stamps[idx[0]]) + off_ns,
                                       int(stamps[idx[-1]]) + off_ns)
        model = EmulatedDA3(rec.gt_source, cam.K, cam.width, cam.height, preset=reference,
                            seed=seed * 1000 + w)
        init = FeedForwardInitializer(model, T_IC[:3, :3], T_IC[:3, 3], rec.rig.time_offset_s or 0.0,
                                      cfg=ff_config)
        for k in ks:
            model.params, model.calls = params[k], 0  # the same draws for every k
            res = init.solve(frames, imu.t_ns, imu.gyro, imu.accel)
            row: dict = {"window": w, "t_s": (t0 - t_lo) * 1e-9, "accepted": isinstance(res, InitResult),
                         **excitation}
            if isinstance(res, InitResult):
                g = interpolate_poses(gt, np.array([res.t_ns], np.int64))
                v_true = gt_velocity(gt, res.t_ns)
                row["velocity_err"], row["gravity_err_deg"] = state_errors(res.R_OI, res.v_OI, g.R[0], v_true)
                row["abs_log_scale_err"] = abs(float(np.log(res.info["scale"] *
                                                            model.last_diagnostics["global_scale"])))
                row["speed"] = float(np.linalg.norm(v_true))
                # what the initializer itself knows (for looking for a gate that sees wrong scale)
                row["inlier_fraction"] = float(res.info["inlier_fraction"])
                row["median_residual"] = float(res.info["median_residual"])
                row["log_refined_over_linear_scale"] = float(np.log(res.info["scale"]
                                                                    / res.info["linear_scale"]))
                row["scale_rel_std"] = float(res.info["scale_rel_std"])
                row["rotation_residual_rms_deg"] = float(res.info["rotation_residual_rms_deg"])
                row["gyro_bias_change"] = float(np.linalg.norm(res.info["gyro_bias_change"]))
                row["scale_bias_sensitivity"] = float(res.info["scale_bias_sensitivity"])
                row["scale_uncertainty"] = float(res.info["scale_uncertainty"])
                row["scale_observed_rel_std"] = float(res.info["scale_observed_rel_std"])
                row["median_depth_m"] = float(res.info["median_depth_m"])
            else:
                row["reason"] = res.reason
            rows[k].append(row)
        w += 1
    return rows


def parse_k(text: str, option: str = "--k") -> list[float]:
    """The numbers of a comma-separated option such as `--k` (the pose-error factors); ConfigError naming
    `option` otherwise."""
    from runtime.errors import ConfigError

    try:
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError as exc:
        raise ConfigError(f"{option} expects comma-separated numbers, got {text!r}") from exc


def run(args: argparse.Namespace) -> int:
    from runtime.errors import ConfigError

    ks = parse_k(args.k)
    from models.emulated_da3.params import POSE_ERROR_FIELDS

    fields = None if not args.fields else [f.strip() for f in args.fields.split(",") if f.strip()]
    bad = sorted(set(fields or []) - set(POSE_ERROR_FIELDS))
    if bad:
        raise ConfigError(f"--fields: unknown pose-error knob(s) {bad}; "
                          f"choose from {list(POSE_ERROR_FIELDS)}")
    result: dict = {"reference": args.reference, "k": ks, "fields": fields or list(POSE_ERROR_FIELDS),
                    "recordings": {}}
    per_window: dict = {}
    from runtime.ffinit import FFInitConfig

    ff_config = FFInitConfig()
    if args.config:
        from runtime.config import load_davio_config

        ff_config = load_davio_config(args.config).ffinit
    if args.max_scale_uncertainty is not None:   # through replace: the configuration's checks apply
        from dataclasses import replace

        ff_config = replace(ff_config, max_scale_uncertainty=args.max_scale_uncertainty)
    result["max_scale_uncertainty"] = ff_config.max_scale_uncertainty
    for name, make in _recordings(args):
        rows = measure_recording(make(), ks, args.reference, args.every, args.seed, args.max_windows, fields,
                                 ff_config)
        result["recordings"][name] = {str(k): summarise(r) for k, r in rows.items()}
        per_window[name] = {str(k): r for k, r in rows.items()}
        if not args.json:
            print(f"{name}: {len(rows[ks[0]])} windows (pose errors = k x {args.reference})")
            print(f"  {'k':>5s} {'accepted':>9s} {'vel m/s':>8s} {'vel p90':>8s} {'grav deg':>9s}"
                  f" {'|log s|':>8s} {'wrong s':>8s}")
            for k in ks:
                s = result["recordings"][name][str(k)]
                f = lambda v: "   -" if v is None else f"{v:8.3f}"  # noqa: E731
                print(f"  {k:5.2f} {s['accepted']:4d}/{s['windows']:<4d} {f(s['velocity_err_median'])}"
                      f" {f(s['velocity_err_p90'])} {f(s['gravity_err_deg_median'])}"
                      f" {f(s['abs_log_scale_err_median'])} {s['wrong_scale']:8d}", flush=True)
    if args.out:
        Path(args.out).write_text(strict_dumps({**result, "per_window": per_window}, indent=2))
    if args.json:
        print(strict_dumps(result))
    return 0
