"""`davio bench startup`: the start-up protocol of the paper (Sec. VI, after Zhang et al.).

Windows start every 10 s over a sequence; in each, every arm restarts from scratch:
  * feedforward: DAVIO's start-up (paper Sec. III): the feed-forward initializer (DA3 window + IMU)
    with buffered-replay handoff AND the filter's own initializers (static, and dynamic while
    moving) armed; whichever filter is ready first publishes. Each window records which one did
    (`source`: "feedforward", "native:static" or "native:dynamic");
  * native: the filter's own initializers alone, no depth model (the paper's OpenVINS row);
  * feedforward_only (diagnosis, not run by default): the feed-forward initializer with the native
    initializers disarmed, to measure it alone.
Scoring as the paper's protocol: each window on its FIRST published trajectory, as is, through the
window's end (success: ATE < 0.5 m, SE(3) alignment, over at least 1 s of poses). T_f is the sensor time
of the first published state after the window start (10 s if none); T_q the start of the first
trajectory when it succeeds and 10 s for every failure. `published_wrong` counts windows whose first
published trajectory failed (a wrong scale published as metric). Secondary, reset-aware columns: a
filter reset after a divergence ends one published trajectory and starts the next; the window then
counts if any trajectory passes, with the time from the failed one's end to the correct one's start.
Gravity-direction and velocity errors are those of the first published state (velocity compared after
the ATE alignment's rotation); `ff |log s|` is the sim(3) scale error of the windows the feed-forward
initializer published. `--pose-error-scale K` and `--depth-error-scale D` set the emulated DA3's error
levels (the sensitivity sweep in BENCHMARKS.md). `--rig-time-offset-error S` hands every arm a rig whose
camera-IMU time offset is S seconds off the recording's (positive: the camera's stamps run later than the rig
says, as a camera stamped on arrival at the host does; negative: earlier).
Recordings are simulated: a motion preset, or images rendered along a real EuRoC ground truth with its
real IMU stream (EuRoC-trajectory mode).
"""
from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from runtime.json_out import strict_dumps
from tools.cli_types import count, nonnegative, number, number_in, positive

NAME = "startup"
HELP = "start-up protocol: DAVIO (feed-forward + native armed) vs native initializer over 10 s windows"
ARMS = ("feedforward", "native", "feedforward_only")
"""The arms `--arms` may name (module docstring)."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--preset", help="motion preset of a simulated recording (e.g. euroc)")
    src.add_argument("--imu", metavar="IMU.csv", help="real EuRoC imu0 CSV (needs --groundtruth)")
    src.add_argument("--sequence", metavar="DIR", help="a euroc_imu_gt folder (groundtruth + imu0.csv)")
    p.add_argument("--groundtruth", metavar="GT.csv", help="EuRoC ground truth CSV for --imu")
    p.add_argument("--camera-stamps", metavar="FILE", help="camera stamps for --imu (default: beside it)")
    p.add_argument("--seconds", type=number, default=None, help="sequence length (preset default 60 s)")
    p.add_argument("--window", type=number_in(0, 3600, low_open=True, unit=" s"), default=10.0,
                   help="window length, s")
    p.add_argument("--every", type=number_in(0.01, 3600, unit=" s"), default=10.0,
                   help="a window starts every S seconds")
    p.add_argument("--max-windows", type=count(1), default=None, help="at most this many windows")
    p.add_argument("--seed", type=count(0), default=0, help="simulation seed")
    p.add_argument("--arms", default="feedforward,native",
                   help=f"comma-separated arms to run, from {', '.join(ARMS)}")
    p.add_argument("--da3", default="base", help="emulated DA3 preset (small, base, large, or <size>_upper: "
                                                 "the upper-bound pose errors, PRESETS.md)")
    p.add_argument("--model-latency", type=number_in(0, 3600, unit=" s"), default=0.5, metavar="S",
                   help="DA3 latency, sensor s")
    p.add_argument("--da3-param", action="append", default=[], metavar="NAME=VALUE",
                   help="override an emulated-DA3 parameter (repeatable; sensitivity studies), "
                        "e.g. rotation_error_median_deg=0.1")
    p.add_argument("--pose-error-scale", type=number, default=None, metavar="K",
                   help="unconditioned DA3 pose errors = K x the upper bound of the preset's size "
                        "(the presets use K = 0.05; 1.0 = the upper-bound table, PRESETS.md)")
    p.add_argument("--depth-error-scale", type=number, default=None, metavar="D",
                   help="multiply the emulated DA3's depth errors (scale jitter, smooth field, noise) by D")
    p.add_argument("--rig-time-offset-error", type=number, default=0.0, metavar="S",
                   help="give the arms a rig whose camera-IMU time offset (t_imu = t_cam + offset) is S s "
                        "off the recording's (positive: the camera's stamps run later than the rig says, "
                        "as a camera stamped on arrival)")
    p.add_argument("--ate-threshold", type=positive, default=0.5, help="success threshold, m")
    p.add_argument("--min-span", type=nonnegative, default=1.0, metavar="S",
                   help="a successful trajectory covers at least S seconds of poses")
    p.add_argument("--config", metavar="TOML", help="configuration for every arm (see config.toml of a run)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--out", metavar="FILE", help="also write the JSON (with per-window rows) here")


def _recording(args: argparse.Namespace) -> Any:
    from drivers.sim import SimConfig, SimRecording
    from runtime.errors import ConfigError

    if args.preset:
        return SimRecording.from_preset(SimConfig(preset=args.preset, seconds=args.seconds or 60.0,
                                                  seed=args.seed))
    cfg = SimConfig(seconds=args.seconds, seed=args.seed)
    if args.sequence:
        return SimRecording.from_euroc_imu_gt(args.sequence, cfg)
    if not args.groundtruth:
        raise ConfigError("--imu needs --groundtruth (the real trajectory the IMU belongs to)")
    return SimRecording.from_trajectory(args.groundtruth, cfg, imu_path=args.imu,
                                        camera_stamps_path=args.camera_stamps)


class _WindowDriver:
    """The events of a recording inside [t0, t1) (frames rendered only inside the window), with the
    recording's rig, or with its camera-IMU time offset off by `time_offset_error_s` (s)."""

    def __init__(self, rec: Any, t0_ns: int, t1_ns: int, time_offset_error_s: float = 0.0) -> None:
        self.rec, self.t0, self.t1 = rec, t0_ns, t1_ns
        self.rig = rec.rig
        if time_offset_error_s:
            self.rig = rec.rig.replace(time_offset_s=(rec.rig.time_offset_s or 0.0) + time_offset_error_s)

    def events(self):
        from runtime.events import ImuSample

        imu = self.rec.imu
        ti, tf = imu.t_ns, self.rec.frame_stamps_ns
        i = int(np.searchsorted(ti, self.t0))
        f = int(np.searchsorted(tf, self.t0))
        while True:
            ti_ok = i < ti.size and ti[i] < self.t1
            tf_ok = f < tf.size and tf[f] < self.t1
            if not (ti_ok or tf_ok):
                return
            if ti_ok and (not tf_ok or ti[i] <= tf[f]):
                yield ImuSample(int(ti[i]), imu.gyro[i].copy(), imu.accel[i].copy())
                i += 1
            else:
                yield self.rec.render(f)[0]
                f += 1


def _overrides(items: list[str]) -> dict:
    from runtime.errors import ConfigError

    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            sep = ""
        if not sep:
            raise ConfigError(f"--da3-param expects NAME=NUMBER, got {item!r}")
    return out


def _judge(seg: list, gt: Any, ate_thr: float, min_span_s: float) -> tuple[bool, Any, float | None]:
    """(success, se3 ATE result or None, sim3 scale error |log s| or None) of one published trajectory:
    success = ATE < ate_thr over at least min_span_s of poses."""
    from runtime.errors import DataError
    from tools.evaluation import ate, ate_degenerate_truth
    from tools.run_io import published_trajectory

    est = published_trajectory(seg)
    span = (int(seg[-1].t_ns) - int(seg[0].t_ns)) * 1e-9
    try:
        res = ate(est, gt, align_method="se3") if len(est) >= 3 else None
        sim = ate(est, gt, align_method="sim3") if len(est) >= 3 and span >= min_span_s else None
    except DataError:   # static or straight-line truth (pure rotation, constant velocity)
        res, sim = ate_degenerate_truth(est, gt), None
    scale_err = None if sim is None else abs(float(np.log(sim.alignment.s)))
    ok = res is not None and res.trans["rmse"] < ate_thr and span >= min_span_s
    return ok, res, scale_err


def _score(pipe: Any, gt: Any, t0_ns: int, window_s: float, ate_thr: float, min_span_s: float = 1.0) -> dict:
    """One window's row, scored as the paper does: on the FIRST published trajectory, as is, through the
    window's end (success: ATE < ate_thr over at least min_span_s of poses; T_q = its start, or window_s
    for a failure). `published_wrong`: something was published and that first trajectory failed.
    Secondary, reset-aware: a filter reset after a divergence starts a new published segment (its own
    odometry frame); `success_reset_aware` if any segment passes, `T_q_reset_aware` its start, and
    `T_correct_after_reset` the time from the end of a failed first trajectory to the start of the first
    passing later one. `source`, gravity and velocity errors are those of the first state of the first
    trajectory; `scale_err` its sim(3) |log s|."""
    from runtime.geometry import interpolate_poses
    from tools.evaluation.state_errors import gt_velocity
    from tools.run_io import published_segments

    segments = published_segments(pipe.published)
    row: dict = {"published": len(pipe.published), "segments": len(segments),
                 "candidates_diverged": pipe.startup.report.candidates_diverged}
    if pipe.startup.publisher is not None:
        row["chi2_rejection_max"] = pipe.startup.publisher.counters.chi2_rejection_fraction_max
    if not segments:
        return {**row, "source": None, "success": False, "published_wrong": False, "T_f": window_s,
                "T_q": window_s, "success_reset_aware": False, "T_q_reset_aware": window_s}
    start = [(int(seg[0].t_ns) - t0_ns) * 1e-9 for seg in segments]
    row["T_f"] = start[0]
    ok, res, row["scale_err"] = _judge(segments[0], gt, ate_thr, min_span_s)
    row["success"], row["published_wrong"] = ok, not ok
    row["T_q"] = start[0] if ok else window_s
    if res is not None:
        row["ate"] = float(res.trans["rmse"])
    row["success_reset_aware"], row["T_q_reset_aware"] = ok, row["T_q"]
    if not ok:
        end_first = (int(segments[0][-1].t_ns) - t0_ns) * 1e-9
        for k, seg in enumerate(segments[1:], start=1):
            if _judge(seg, gt, ate_thr, min_span_s)[0]:
                row["success_reset_aware"], row["T_q_reset_aware"] = True, start[k]
                row["T_correct_after_reset"] = start[k] - end_first
                break
    first = segments[0][0]
    row["source"] = first.source
    truth = interpolate_poses(gt, np.array([first.t_ns], np.int64))
    up_est = first.R_OI.T @ np.array([0.0, 0.0, 1.0])
    up_gt = truth.R[0].T @ np.array([0.0, 0.0, 1.0])
    row["gravity_err_deg"] = float(np.degrees(np.arccos(np.clip(up_est @ up_gt, -1.0, 1.0))))
    if res is not None:
        R_al = res.alignment.R
        row["velocity_err"] = float(np.linalg.norm(R_al @ first.v_OI - gt_velocity(gt, int(first.t_ns))))
    return row


def _summary(rows: list[dict]) -> dict:
    def med(key: str, only_success: bool = True) -> float | None:
        vals = [r[key] for r in rows if r.get(key) is not None
                and (key.startswith(("T_f", "T_q")) or not only_success or r["success"])]
        return float(np.median(vals)) if vals else None

    sources: dict[str, int] = {}
    for r in rows:
        key = r.get("source") or "none"
        sources[key] = sources.get(key, 0) + 1
    ff_scale = [r["scale_err"] for r in rows
                if r.get("source") == "feedforward" and r.get("scale_err") is not None]
    return {"windows": len(rows), "successes": int(sum(r["success"] for r in rows)),
            "published_wrong": int(sum(r.get("published_wrong", False) for r in rows)),
            "successes_reset_aware": int(sum(r.get("success_reset_aware", False) for r in rows)),
            "T_f_median": med("T_f"), "T_q_median": med("T_q"),
            "T_q_reset_aware_median": med("T_q_reset_aware"),
            "T_correct_after_reset_median": med("T_correct_after_reset", only_success=False),
            "gravity_err_deg_median": med("gravity_err_deg"), "velocity_err_median": med("velocity_err"),
            "ate_median": med("ate"), "sources": sources,
            "ff_scale_err": _distribution(ff_scale),
            "ff_extended_windows": int(sum(r.get("source") == "feedforward"
                                           and r.get("ff_extension_accepted", 0) > 0 for r in rows))}


def _distribution(vals: list[float]) -> dict | None:
    """Median, 90th percentile, max and the share above 10 % of |log s| over the accepted windows."""
    if not vals:
        return None
    a = np.asarray(vals)
    return {"n": int(a.size), "median": float(np.median(a)), "p90": float(np.percentile(a, 90)),
            "max": float(a.max()), "above_10pct": int(np.sum(a > np.log(1.1)))}


DEPTH_ERROR_FIELDS = ("image_log_scale_sigma", "image_log_scale_sigma_cond", "window_log_scale_sigma_cond",
                      "field_sigma", "field_sigma_cond", "noise_sigma")
"""The emulated DA3's depth-error knobs that --depth-error-scale multiplies."""


def _error_scales(args: argparse.Namespace) -> dict:
    """Emulator overrides for --pose-error-scale K (K x POSE_ERRORS_UPPER of the preset's size) and
    --depth-error-scale D (D x the preset's depth-error knobs)."""
    from models.emulated_da3.params import POSE_ERRORS_UPPER, make_params
    from runtime.errors import ConfigError

    out: dict = {}
    size = args.da3.removesuffix("_upper")
    if args.pose_error_scale is not None:
        k = args.pose_error_scale
        if not (k >= 0 and np.isfinite(k)) or size not in POSE_ERRORS_UPPER:
            raise ConfigError(f"--pose-error-scale needs a finite K >= 0 and a sized preset, got {k}, "
                              f"{args.da3}")
        out.update({name: v * k for name, v in POSE_ERRORS_UPPER[size].items()})
    if args.depth_error_scale is not None:
        d = args.depth_error_scale
        if not (d >= 0 and np.isfinite(d)):
            raise ConfigError(f"--depth-error-scale needs a finite D >= 0, got {d}")
        base = make_params(args.da3)
        out.update({name: getattr(base, name) * d for name in DEPTH_ERROR_FIELDS})
    return out


def _arms(names: str, base: Any) -> dict:
    """The configurations of the named arms (module docstring), in the order given."""
    from runtime.errors import ConfigError

    # start-up is measured alone: the mapper would share the model worker with post-reset start-up windows
    base = replace(base, mapping=replace(base.mapping, enabled=False))
    both = replace(base, use_dynamic_init=True)
    known = {
        "feedforward": both,
        "native": replace(both, startup=replace(base.startup, feedforward=False)),
        "feedforward_only": replace(base, startup=replace(base.startup, native=False)),
    }
    arms = [a.strip() for a in names.split(",") if a.strip()]
    bad = [a for a in arms if a not in known]
    if bad or not arms or len(set(arms)) != len(arms):
        raise ConfigError(f"--arms expects distinct names from {', '.join(ARMS)}, got {names!r}")
    return {a: known[a] for a in arms}


def _short(source: str) -> str:
    """A compact name of the initializer that published (for the table)."""
    return source.replace("feedforward", "ff").replace("native:", "")


def run(args: argparse.Namespace) -> int:
    from models.emulated_da3 import EmulatedDA3, make_params
    from runtime.config import DavioConfig, load_davio_config
    from runtime.errors import ConfigError
    from tools.run_session import run_pipeline

    overrides = {**_error_scales(args), **_overrides(args.da3_param)}
    if not abs(args.rig_time_offset_error) < 1.0:
        raise ConfigError(f"--rig-time-offset-error must be a finite number of seconds below 1 in size, got "
                          f"{args.rig_time_offset_error}")
    arms = _arms(args.arms, load_davio_config(args.config) if args.config else DavioConfig())
    make_params(args.da3, **overrides)  # an unknown preset or parameter fails before the slow part
    rec = _recording(args)
    gt = rec.groundtruth()
    cam = rec.rig.camera
    t_first = int(max(rec.imu.t_ns[0], rec.frame_stamps_ns[0]))
    t_last = int(min(rec.imu.t_ns[-1], rec.frame_stamps_ns[-1]))
    starts = []
    t = t_first
    while t + args.window * 1e9 <= t_last + 1:
        starts.append(t)
        t += int(args.every * 1e9)
    if args.max_windows:
        starts = starts[: args.max_windows]
    rows: dict[str, list] = {k: [] for k in arms}
    for w, t0 in enumerate(starts):
        t1 = t0 + int(args.window * 1e9)
        for arm, cfg in arms.items():
            model = None
            if cfg.startup.feedforward:
                model = EmulatedDA3(rec.gt_source, cam.K, cam.width, cam.height, preset=args.da3,
                                    seed=args.seed * 1000 + w, **overrides)
            driver = _WindowDriver(rec, t0, t1, args.rig_time_offset_error)
            res = run_pipeline(driver, model, cfg, model_latency_s=args.model_latency, show_progress=False)
            row = _score(res.pipeline, gt, t0, args.window, args.ate_threshold, args.min_span)
            srep = res.pipeline.startup.report
            row.update({"window": w, "start_s": (t0 - t_first) * 1e-9, "ff_rejections": srep.ff_rejections,
                        "ff_extensions": srep.ff_extensions,
                        "ff_extension_accepted": srep.ff_extension_accepted,
                        "ff_extension_rejections": srep.ff_extension_rejections,
                        "time_offset_findings": srep.time_offset_findings,
                        "time_offset_adopted_s": srep.time_offset_adopted_s,
                        "ff_time_offset_corrected": srep.ff_time_offset_corrected})
            rows[arm].append(row)
            if not args.json:
                print(f"  window {w:2d} ({row['start_s']:6.1f} s) {arm:16s} "
                      f"{'ok ' if row['success'] else 'FAIL'} T_f {row['T_f']:5.2f} s"
                      f"  ATE {row.get('ate', float('nan')):.3f} m  by {row['source']}"
                      + (f" (re-solved {srep.ff_extensions}x over a longer span)"
                         if srep.ff_extensions else ""),
                      flush=True)
    result = {arm: _summary(r) for arm, r in rows.items()}
    result["source"] = rec.info
    result["arms"] = list(arms)
    result["emulated_da3"] = args.da3
    result["emulated_da3_overrides"] = overrides
    result["pose_error_scale"] = args.pose_error_scale
    result["depth_error_scale"] = args.depth_error_scale
    result["model_latency_s"] = args.model_latency
    result["rig_time_offset_error_s"] = args.rig_time_offset_error
    if args.out:
        Path(args.out).write_text(strict_dumps({**result, "per_window": rows}, indent=2))
    if args.json:
        print(strict_dumps(result))
        return 0
    from rich.console import Console
    from rich.table import Table

    tab = Table(title=f"start-up over {len(starts)} windows ({rec.info.get('source')})")
    for col in ("initializer", "success", "wrong", "T_f (s)", "T_q (s)", "reset-aware", "grav (deg)",
                "vel (m/s)", "ATE (m)", "ff |log s| med/max", "by"):
        tab.add_column(col)
    fmt = lambda v: "-" if v is None else f"{v:.2f}" if abs(v) >= 0.1 else f"{v:.3f}"  # noqa: E731
    for arm in arms:
        s = result[arm]
        sc = s["ff_scale_err"]
        tab.add_row(arm, f"{s['successes']}/{s['windows']}", str(s["published_wrong"]), fmt(s["T_f_median"]),
                    fmt(s["T_q_median"]), f"{s['successes_reset_aware']}/{s['windows']} T_q "
                    f"{fmt(s['T_q_reset_aware_median'])}", fmt(s["gravity_err_deg_median"]),
                    fmt(s["velocity_err_median"]), fmt(s["ate_median"]),
                    "-" if sc is None else f"{fmt(sc['median'])}/{fmt(sc['max'])}",
                    ", ".join(f"{_short(k)} {v}" for k, v in sorted(s["sources"].items())))
    Console().print(tab)
    return 0
