"""`davio bench online-calib DIR`: online camera-IMU calibration on the OpenVINS simulator's measurements.

The filter is given a calibration perturbed from the truth in sim_info.txt (default 2 deg rotation,
2 cm lever arm, 5 ms time offset, random directions from --seed), estimates extrinsics and time offset
online, and we report the calibration errors at the end and their mean over the last 10 s.
Goal (issue 4): below 0.3 deg / 0.5 cm / 1 ms.

With --intrinsics the filter also starts from perturbed camera intrinsics (default focal +1.5 %, principal
point +3 px, k1 +0.02) and estimates them online (MsckfConfig.calib_intrinsics), with prior stds equal to
the start errors (at least OpenVINS's 1 px / 0.005); we report the focal (%), principal point (px) and
distortion errors next to the start ones.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from runtime.json_out import strict_dumps
from tools.cli_types import count, number_in

NAME = "online-calib"
HELP = "online extrinsic / time-offset calibration from perturbed values on the OpenVINS simulator data"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("folder", type=Path, help="openvins_sim run folder (see openvins-sim)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    p.add_argument("--out", type=Path, default=None, help="also write the JSON result to this file")
    p.add_argument("--max-seconds", type=number_in(1, 1e6, unit=" s"), default=60.0,
                   help="seconds of data to use from the start")
    p.add_argument("--rot-deg", type=number_in(0, 90, unit=" deg"), default=2.0,
                   help="initial rotation error of R_IC, deg")
    p.add_argument("--pos-cm", type=number_in(0, 100, unit=" cm"), default=2.0,
                   help="initial lever-arm error, cm")
    p.add_argument("--dt-ms", type=number_in(-1000, 1000, unit=" ms"), default=5.0,
                   help="initial time-offset error, ms")
    p.add_argument("--seed", type=count(0), default=0, help="seed of the perturbation directions")
    p.add_argument("--intrinsics", action="store_true", help="also perturb and estimate the intrinsics")
    p.add_argument("--focal-pct", type=number_in(0, 50, unit=" %"), default=1.5,
                   help="initial fx, fy error with --intrinsics, %%")
    p.add_argument("--center-px", type=number_in(0, 500, unit=" px"), default=3.0,
                   help="initial cx, cy error with --intrinsics, px")
    p.add_argument("--k1", type=number_in(-1, 1), default=0.02, help="initial k1 error with --intrinsics")


def perturbed_calibration(
    R_IC: np.ndarray, p_IC: np.ndarray, t_d: float, rot_deg: float, pos_cm: float, dt_ms: float, seed: int
) -> tuple[np.ndarray, np.ndarray, float]:
    """The true calibration moved by the given amounts along random directions."""
    from runtime.msckf.so3_kernels import exp3

    rng = np.random.default_rng(seed)
    a = rng.standard_normal(3)
    b = rng.standard_normal(3)
    R0 = R_IC @ exp3(np.radians(rot_deg) * a / np.linalg.norm(a))
    p0 = p_IC + 0.01 * pos_cm * b / np.linalg.norm(b)
    t0 = t_d + 1e-3 * dt_ms * (1.0 if rng.random() < 0.5 else -1.0)
    return R0, p0, t0


def perturbed_intrinsics(params: np.ndarray, focal_pct: float, center_px: float, dk1: float) -> np.ndarray:
    """The camera parameters [fx, fy, cx, cy, d0..d4] with fx, fy scaled by (1 + focal_pct / 100), cx, cy
    moved by center_px and the first distortion coefficient (k1) moved by dk1."""
    p = np.array(params, dtype=float)
    p[0:2] *= 1.0 + 0.01 * focal_pct
    p[2:4] += center_px
    p[4] += dk1
    return p


def intrinsics_errors(params: np.ndarray, true: np.ndarray) -> tuple[float, float, float]:
    """(largest |focal| error %, principal point error px (norm), largest |distortion| error over d0..d3)."""
    p, t = np.asarray(params, dtype=float), np.asarray(true, dtype=float)
    return (
        float(100 * np.max(np.abs(p[0:2] / t[0:2] - 1.0))),
        float(np.linalg.norm(p[2:4] - t[2:4])),
        float(np.max(np.abs(p[4:8] - t[4:8]))),
    )


def intrinsics_prior(cfg: object, start: np.ndarray, true: np.ndarray) -> object:
    """cfg with calib_intrinsics on and prior stds of the start errors (at least cfg's defaults)."""
    err = np.abs(np.asarray(start) - np.asarray(true))
    return cfg.updated(
        calib_intrinsics=True,
        sigma_calib_focal=max(cfg.sigma_calib_focal, float(err[0:2].max())),
        sigma_calib_center=max(cfg.sigma_calib_center, float(err[2:4].max())),
        sigma_calib_distortion=max(cfg.sigma_calib_distortion, float(err[4:8].max())),
    )


def calibration_errors(
    R: np.ndarray, p: np.ndarray, t: float, R_true: np.ndarray, p_true: np.ndarray, t_true: float
) -> tuple[float, float, float]:
    """(rotation deg, lever arm cm, |time offset| ms) errors."""
    from runtime.msckf.so3_kernels import log3

    return (
        float(np.degrees(np.linalg.norm(log3(R.T @ R_true)))),
        float(100 * np.linalg.norm(p - p_true)),
        float(1e3 * abs(t - t_true)),
    )


def with_camera_params(sim: object, params: np.ndarray) -> object:
    """A copy of a SimRun whose rig's camera has the given [fx, fy, cx, cy, d0..d4] (same model and size)."""
    import dataclasses

    cam = sim.rig.camera
    nd = len(cam.distortion)
    new_cam = type(cam)(cam.width, cam.height, *params[0:4], distortion=params[4 : 4 + nd])
    return dataclasses.replace(sim, rig=dataclasses.replace(sim.rig, camera=new_cam))


def run(args: argparse.Namespace) -> int:
    from runtime.msckf.camera_kernels import CameraParams
    from tools.benchmarks.openvins_sim import evaluate, load_sim_folder, run_filter

    sim = load_sim_folder(args.folder, args.max_seconds)       # its DataError names the file
    R_IC, p_IC, t_d = sim.true_calib
    start = perturbed_calibration(R_IC, p_IC, t_d, args.rot_deg, args.pos_cm, args.dt_ms, args.seed)
    cfg = sim.config.updated(calib_extrinsics=True, calib_time_offset=True)
    true_k = CameraParams.from_camera(sim.rig.camera).params
    start_k = true_k
    if args.intrinsics:
        start_k = perturbed_intrinsics(true_k, args.focal_pct, args.center_px, args.k1)
        cfg = intrinsics_prior(cfg, start_k, true_k)
        sim = with_camera_params(sim, start_k)
    hist: list = []
    snaps, report = run_filter(
        sim,
        cfg,
        calib=start,
        callback=lambda s: hist.append((s.t_cam_ns, s.R_IC, s.p_IC, s.time_offset_s, s.intrinsics)),
    )
    if not hist:
        from runtime.errors import DataError

        raise DataError("the filter produced no state", args.folder)
    errs = np.array([calibration_errors(R, p, t, R_IC, p_IC, t_d) for _, R, p, t, _ in hist])
    t_rel = np.array([h[0] for h in hist], dtype=np.int64)
    last = t_rel >= t_rel[-1] - 10_000_000_000
    start_errs = calibration_errors(*start, R_IC, p_IC, t_d)
    res = {
        "start_rot_deg": start_errs[0],
        "start_pos_cm": start_errs[1],
        "start_dt_ms": start_errs[2],
        "rot_err_deg": float(errs[-1, 0]),
        "pos_err_cm": float(errs[-1, 1]),
        "dt_err_ms": float(errs[-1, 2]),
        "rot_err_deg_last10s": float(errs[last, 0].mean()),
        "pos_err_cm_last10s": float(errs[last, 1].mean()),
        "dt_err_ms_last10s": float(errs[last, 2].mean()),
        "seconds": args.max_seconds,
        "divergence_resets": report["divergence_resets"],
        "ms_per_frame": report["ms_per_frame"],
    }
    names = ("focal_pct", "center_px", "dist")
    if args.intrinsics:
        kerrs = np.array([intrinsics_errors(h[4], true_k) for h in hist])
        res.update({f"start_{n}": v for n, v in zip(names, intrinsics_errors(start_k, true_k), strict=True)})
        res.update({f"{n}_err": float(kerrs[-1, j]) for j, n in enumerate(names)})
        res.update({f"{n}_err_last10s": float(kerrs[last, j].mean()) for j, n in enumerate(names)})
        res["intrinsics_true"] = true_k[:8].tolist()
        res["intrinsics_final"] = hist[-1][4][:8].tolist()
        res["intrinsics_std"] = snaps[-1].intrinsics_std.tolist() if snaps else None
    res.update({f"traj_{k}": v for k, v in evaluate(sim, snaps).items()})
    if args.out is not None:
        args.out.write_text(strict_dumps(res, indent=2))
    if args.json:
        print(strict_dumps(res))
        return 0
    print(
        f"online-calib on {args.folder}, {args.max_seconds:g} s, seed {args.seed} "
        "(goal: < 0.3 deg / 0.5 cm / 1 ms)"
    )
    cols = ("rot deg", "pos cm", "dt ms") + (("focal %", "pp px", "dist") if args.intrinsics else ())
    final = ("rot_err_deg", "pos_err_cm", "dt_err_ms") + (
        tuple(f"{n}_err" for n in names) if args.intrinsics else ()
    )
    start_keys = ("start_rot_deg", "start_pos_cm", "start_dt_ms") + (
        tuple(f"start_{n}" for n in names) if args.intrinsics else ()
    )
    rows = (
        ("start", [res[k] for k in start_keys]),
        ("final", [res[k] for k in final]),
        ("mean last 10 s", [res[f"{k}_last10s"] for k in final]),
    )
    print(f"{'':<18}" + "".join(f"{c:>10}" for c in cols))
    for name, vals in rows:
        print(f"{name:<18}" + "".join(f"{v:>10.4f}" for v in vals))
    print(
        f"trajectory: RMSE {res.get('traj_rmse_pos_m', float('nan')):.3f} m, "
        f"{res.get('traj_rmse_ori_deg', float('nan')):.3f} deg; {res['ms_per_frame']:.2f} ms/frame; "
        f"divergence resets {res['divergence_resets']}"
    )
    return 0
