"""`davio bench init-cost`: what the dynamic initializer's attempts cost the tracking thread, with the
refinement's solver (`dynamic_init.mle_solver`) and with the scipy one it replaced, in the same run.

The dynamic initializer runs on the tracking thread, at every frame until a filter publishes. An attempt
that gets past the window checks fits two-view rotations (the rotation check), solves the linear system
and refines the window by nonlinear least squares; until the thirty-first session the refinement was
scipy's least_squares with forward differences over the Jacobian's sparsity pattern ("scipy-fd") and cost
1-2 s on 2 cores, which live means the tracking thread stalls and the images of that time are dropped; it
is now Levenberg-Marquardt on the normal equations with the analytic Jacobian ("lm").

Attempts: two dynamic initializers, one per `dynamic_init.mle_solver`, are fed the same KLT tracks and
IMU of each simulated recording and attempt at every frame, whatever the outcome (a run stops at the first
success), with their other settings as a run's, and with the BLAS pools limited as a run's estimator
limits them (`msckf.blas_threads`). Per solver: the attempts that reached the refinement
(succeeded, or refused after it) and their time (median, p90, max), and the other attempts' time; and for
the attempts both accepted, the largest difference between the two states (newest keyframe: position,
velocity, gravity direction) and between their covariances' standard deviations (relative); and each
solver's median and largest error against the truth (velocity in the IMU frame, gravity direction), how
many accepted windows had gravity more than 1 deg off, and more than 3 of the window's own standard
deviations off (the tilt's largest, from the reported covariance); and how many windows were refused
because the refinement did not converge within `mle_max_iterations` evaluations.

`--live`: each recording is also pushed into a live Session at its real rate (every IMU sample kept; an
image waiting behind two others is dropped, as `davio live` does), once per solver, native initializers
only: images dropped, the tracking thread's longest step and when the first pose was published.
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from runtime.msckf.init_dynamic_config import MLE_SOLVERS
from tools.cli_types import count, number

NAME = "init-cost"
HELP = "the dynamic initializer's attempts on the tracking thread, by the refinement's solver"
DESCRIPTION = __doc__


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--preset", action="append", default=None,
                   help="motion preset (repeatable; default: handheld, aggressive, slow)")
    p.add_argument("--seconds", type=number, default=8.0, help="recording length, s")
    p.add_argument("--seed", type=count(0), default=4)
    p.add_argument("--live", action="store_true",
                   help="also push each recording into a live Session at its real rate (images dropped)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--out", metavar="FILE.json", help="also write the JSON here")


def _stats(ms: list[float]) -> dict:
    a = np.asarray(ms, float)
    if a.size == 0:
        return {"n": 0, "median_ms": None, "p90_ms": None, "max_ms": None}
    return {"n": int(a.size), "median_ms": float(np.median(a)), "p90_ms": float(np.percentile(a, 90)),
            "max_ms": float(a.max())}


def _reached_refinement(init, result) -> bool:
    last = init.log.last
    return result is not None or (last is not None and last.code in ("mle_failed", "mle_not_converged",
                                                                     "implausible_bias"))


def _not_converged(init, result) -> bool:
    last = init.log.last
    return result is None and last is not None and last.code == "mle_not_converged"


def attempts(rig, events, motion=None) -> dict:
    """Both solvers' dynamic initializers on the same tracks and IMU, attempting at every frame; with the
    recording's true motion (a PoseSpline of T_WI, IMU clock, z up), each accepted state's errors."""
    from runtime.events import ImuSample
    from runtime.msckf.blas_threads import limit_blas_threads
    from runtime.msckf.config import MsckfConfig
    from runtime.msckf.init_dynamic import DynamicInitializer
    from runtime.msckf.init_dynamic_config import DynamicInitConfig
    from runtime.msckf.tracker import KltTracker

    # a run's estimator, which owns the initializers, limits the BLAS pools before they attempt; so here
    blas_threads = MsckfConfig().blas_threads
    if blas_threads is not None:
        limit_blas_threads(blas_threads)
    inits = {solver: DynamicInitializer(rig.camera, rig.T_IC, DynamicInitConfig(mle_solver=solver),
                                     imu_noise=rig.imu, time_offset_s=rig.time_offset_s or 0.0)
             for solver in MLE_SOLVERS}
    refined: dict[str, list[float]] = {solver: [] for solver in MLE_SOLVERS}
    other: dict[str, list[float]] = {solver: [] for solver in MLE_SOLVERS}
    diffs = {"position_m": 0.0, "velocity_m_s": 0.0, "gravity_deg": 0.0, "sigma_relative": 0.0}
    accepted = {solver: 0 for solver in MLE_SOLVERS}
    not_converged = {solver: 0 for solver in MLE_SOLVERS}
    errors: dict[str, dict[str, list[float]]] = {
        solver: {"velocity_m_s": [], "gravity_deg": [], "gravity_sigmas": []} for solver in MLE_SOLVERS}
    both = frames = 0
    tracker = KltTracker(rig.camera)
    for ev in events:
        if isinstance(ev, ImuSample):
            for init in inits.values():
                init.feed_imu(ev)
            continue
        res = tracker.track(ev)
        frames += 1
        out = {}
        for solver, init in inits.items():
            init.feed_tracks(res.t_ns, res.ids, res.uv)
            t0 = time.perf_counter()
            out[solver] = init.try_initialize()
            ms = (time.perf_counter() - t0) * 1e3
            (refined if _reached_refinement(init, out[solver]) else other)[solver].append(ms)
            accepted[solver] += out[solver] is not None
            not_converged[solver] += _not_converged(init, out[solver])
            if motion is not None and out[solver] is not None:
                for k, v in _errors(out[solver], motion).items():
                    if v is not None:
                        errors[solver][k].append(v)
        a, b = out["lm"], out["scipy-fd"]
        if a is not None and b is not None:
            both += 1
            up_a, up_b = a.gravity_in_imu, b.gravity_in_imu
            sd_a, sd_b = np.sqrt(np.diag(a.cov)), np.sqrt(np.diag(b.cov))
            diffs["position_m"] = max(diffs["position_m"], float(np.linalg.norm(a.p_OI - b.p_OI)))
            diffs["velocity_m_s"] = max(diffs["velocity_m_s"], float(np.linalg.norm(a.v_OI - b.v_OI)))
            diffs["gravity_deg"] = max(diffs["gravity_deg"], float(np.degrees(np.arccos(
                np.clip(up_a @ up_b, -1.0, 1.0)))))
            diffs["sigma_relative"] = max(diffs["sigma_relative"], float(np.max(np.abs(sd_a - sd_b) / sd_b)))
    return {"frames": frames, "accepted_by_both": both,
            "by_solver": {solver: {"accepted": accepted[solver], "refined": _stats(refined[solver]),
                                   "other": _stats(other[solver]),
                                   "not_converged": not_converged[solver],
                                   "median_error": {k: float(np.median(v)) if v else None
                                                    for k, v in errors[solver].items()},
                                   "max_error": {k: float(np.max(v)) if v else None
                                                 for k, v in errors[solver].items()},
                                   "gravity_over_1_deg": sum(e > 1.0 for e in errors[solver]["gravity_deg"]),
                                   "gravity_over_3_sigma": sum(e > 3.0
                                                               for e in errors[solver]["gravity_sigmas"])}
                          for solver in MLE_SOLVERS},
            "largest_difference": diffs if both else None}


def _errors(res, motion) -> dict:
    """Velocity (IMU frame, m/s) and gravity direction (deg) errors of an InitResult against the truth, and
    the gravity error in the tilt's standard deviations (from the reported covariance)."""
    truth = motion.sample(np.array([res.t_ns], dtype=np.int64))
    R_WI, v_W = truth.R[0], truth.v[0]
    v_err = np.linalg.norm(res.R_OI.T @ res.v_OI - R_WI.T @ v_W)
    up = np.clip(res.gravity_in_imu @ R_WI[2, :], -1.0, 1.0)
    g_deg = float(np.degrees(np.arccos(up)))
    sigmas = None if res.cov is None else g_deg / tilt_sigma_deg(res)
    return {"velocity_m_s": float(v_err), "gravity_deg": g_deg, "gravity_sigmas": sigmas}


def tilt_sigma_deg(res) -> float:
    """The largest standard deviation (deg) of the gravity direction in the newest IMU frame, from the
    covariance of its orientation error theta (R_OI Exp(theta)): g_I = Exp(-theta) R_OI^T g_O moves by
    [g_I]x theta, whose component along g_I is zero."""
    from runtime.geometry.so3 import skew

    J = skew(res.gravity_in_imu / np.linalg.norm(res.gravity_in_imu))
    return float(np.degrees(np.sqrt(np.linalg.eigvalsh(J @ res.cov[0:3, 0:3] @ J.T)[-1])))


def live(rig, events: list, solver: str) -> dict:
    """Push `events` into a live Session at their real rate; images dropped and the longest step."""
    from runtime.config import DavioConfig
    from runtime.events import ImuSample
    from runtime.session import Session

    cfg = DavioConfig()
    cfg = replace(cfg, dynamic_init=replace(cfg.dynamic_init, mle_solver=solver))
    first: list[int] = []
    t_start = events[0].t_ns
    with Session(rig, None, cfg, on_pose=lambda p: first.append(p.t_ns) if not first else None) as s:
        wall0 = time.monotonic()
        for ev in events:
            delay = wall0 + (ev.t_ns - t_start) * 1e-9 - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            if isinstance(ev, ImuSample):
                s.add_imu(ev.t_ns, ev.gyro, ev.accel)
            else:
                s.add_image(ev.t_ns, ev.image)
    rep = s.result.scheduler
    ms = np.asarray(rep.per_frame_ms, float)
    return {"solver": solver, "images_dropped": int(rep.frames_dropped), "images_tracked": int(ms.size),
            "longest_step_ms": float(ms.max()) if ms.size else None,
            "first_pose_s": (first[0] - t_start) * 1e-9 if first else None}


def run(args: argparse.Namespace) -> int:
    from drivers.sim import SimConfig, SimRecording
    from runtime.json_out import strict_dumps

    result: dict = {"seconds": args.seconds, "seed": args.seed, "recordings": {}}
    say = (lambda *a, **k: None) if args.json else print
    say("the dynamic initializer's attempts at every frame (ms on this thread), by the refinement's solver")
    say(f"  {'recording':10s} {'solver':9s} {'accepted':>8s} {'refined':>7s} {'median':>7s} {'p90':>7s} "
        f"{'max':>7s} | {'other':>5s} {'median':>7s} {'max':>7s} | not converged | error: velocity, gravity "
        "(median; max); gravity > 1 deg, > 3 sigma")
    for preset in args.preset or ("handheld", "aggressive", "slow"):
        rec = SimRecording.from_preset(SimConfig(preset=preset, seconds=args.seconds, seed=args.seed))
        events = list(rec.events())
        r = attempts(rec.rig, events, rec.motion)
        for solver, j in r["by_solver"].items():
            f, o = j["refined"], j["other"]
            say(f"  {preset:10s} {solver:9s} {j['accepted']:8d} {f['n']:7d} {_ms(f['median_ms'])} "
                f"{_ms(f['p90_ms'])} {_ms(f['max_ms'])} | {o['n']:5d} {_ms(o['median_ms'])} "
                f"{_ms(o['max_ms'])} | {j['not_converged']:13d} | {_err(j['median_error'])}; "
                f"{_err(j['max_error'])}; {j['gravity_over_1_deg']}, {j['gravity_over_3_sigma']}", flush=True)
        d = r["largest_difference"]
        if d is not None:
            say(f"  {'':10s} both accepted {r['accepted_by_both']} windows; largest difference: "
                f"{d['position_m'] * 1e3:.3f} mm, {d['velocity_m_s'] * 1e3:.3f} mm/s, "
                f"gravity {d['gravity_deg']:.4f} deg, sigmas {d['sigma_relative']:.1%}", flush=True)
        if args.live:
            r["live"] = [live(rec.rig, events, solver) for solver in MLE_SOLVERS]
            for row in r["live"]:
                first = "-" if row["first_pose_s"] is None else f"{row['first_pose_s']:.2f} s"
                say(f"  {preset:10s} live, {row['solver']:9s}: {row['images_dropped']} images dropped of "
                    f"{row['images_dropped'] + row['images_tracked']}, longest step "
                    f"{row['longest_step_ms']:.0f} ms, first pose at {first}", flush=True)
        result["recordings"][preset] = r
    if args.out:
        Path(args.out).write_text(strict_dumps(result, indent=1))
    if args.json:
        print(strict_dumps(result))
    return 0


def _err(e: dict) -> str:
    if e["velocity_m_s"] is None:
        return "-"
    return f"{e['velocity_m_s'] * 1e3:.1f} mm/s, {e['gravity_deg']:.3f} deg"


def _ms(v: float | None) -> str:
    return f"{'-':>7s}" if v is None else f"{v:7.1f}"
