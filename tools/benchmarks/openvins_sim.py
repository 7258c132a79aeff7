"""`davio bench openvins-sim DIR`: our MSCKF on the OpenVINS simulator's measurements.

The folder (shared/data/openvins_sim/<run>, see its README) holds the IMU samples and feature tracks that
OpenVINS itself was fed, the true state at camera times, the true calibration and initial state
(sim_info.txt), OpenVINS's configuration files and its own per-frame result. We run our filter on the same
inputs, initialised from the same true state with the equivalent configuration, and print position /
orientation RMSE, NEES and ms per frame beside OpenVINS's figures.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from runtime.json_out import strict_dumps
from tools.benchmarks.openvins_sim_data import SimRun, load_sim_folder  # noqa: F401 (re-exported)
from tools.cli_types import count, number, number_in

NAME = "openvins-sim"
HELP = "our MSCKF on the OpenVINS simulator's IMU samples and feature tracks, beside OpenVINS's result"


# ----------------------------------------------------------------------------- running
def perturbed_init(init: tuple, config: object, seed: int) -> tuple:
    """The initial state `init` = (t_ns, R_OI, p, v, bg, ba) with an error drawn from the filter's initial
    covariance diag(init_sigma_*^2): R = R_true Exp(dtheta) (body-frame error, the filter's convention),
    p, v, bg, ba plus Gaussian offsets. Started this way, a consistent filter's NEES averages the state
    dimension (3) also along the unobservable directions (heading, global position)."""
    from runtime.msckf.so3_kernels import exp3

    rng = np.random.default_rng(seed)
    t0, R0, p0, v0, bg0, ba0 = init
    sig = (config.init_sigma_ori, config.init_sigma_pos, config.init_sigma_vel, config.init_sigma_bg,
           config.init_sigma_ba)
    d = [s * rng.standard_normal(3) for s in sig]
    return (t0, np.asarray(R0) @ exp3(d[0]), p0 + d[1], v0 + d[2], bg0 + d[3], ba0 + d[4])


def run_filter(
    run: SimRun, config: object | None = None, calib: tuple | None = None, callback: object | None = None,
    init: tuple | None = None,
) -> tuple[list, dict]:
    """Feed the run's IMU and tracks in time order; returns (snapshots, report). calib=(R_IC, p_IC, dt)
    replaces the calibration given to the filter (online-calibration experiments); init replaces the
    true initial state run.init (same layout)."""
    from runtime.events import ImuSample
    from runtime.msckf.estimator import MsckfEstimator

    est = MsckfEstimator(run.rig, config or run.config)
    if calib is not None:
        est.set_calibration(*calib)
    t0, R0, p0, v0, bg0, ba0 = run.init if init is None else init
    est.initialize_from_state(t0, R0, p0, v0, bg0, ba0, None, source="ground truth")
    snaps = []
    k_imu = 0
    n_imu = run.imu_t.size
    for tf, (ids, uv) in zip(run.feat_t, run.feat_slices, strict=True):
        # IMU samples up to and including the first sample past the frame (the frame then processes)
        while k_imu < n_imu and run.imu_t[k_imu] <= tf:
            snaps += est.feed_imu(ImuSample(int(run.imu_t[k_imu]), run.imu_w[k_imu], run.imu_a[k_imu]))
            k_imu += 1
        new = est.feed_tracks(int(tf), ids, uv)
        while not new and k_imu < n_imu and est._pending:
            new = est.feed_imu(ImuSample(int(run.imu_t[k_imu]), run.imu_w[k_imu], run.imu_a[k_imu]))
            k_imu += 1
        snaps += new
        if callback is not None:
            for s in new:
                callback(s)
    snaps += est.flush()
    return snaps, est.report()


FRAME_COLUMNS = (
    "t_cam_s err_px err_py err_pz err_thx err_thy err_thz nees_pos nees_ori "
    "sig_px sig_py sig_pz sig_thx sig_thy sig_thz"
).split()


def frame_errors(run: SimRun, snaps: list) -> np.ndarray:
    """Per evaluated frame (rows in FRAME_COLUMNS order): camera time (s); position error p_true - p_est
    (m, O frame); orientation error as a rotation vector in the O frame, log(R_true R_est^T) (rad; its z
    component is the heading error about gravity); position and orientation NEES; the filter's standard
    deviations of those six components, in the same frames (m, rad)."""
    from runtime.msckf.so3_kernels import log3

    index = {int(t): i for i, t in enumerate(run.gt_t)}
    rows = []
    for s in snaps:
        i = index.get(int(s.t_cam_ns))
        if i is None:
            continue
        dp = run.gt_p[i] - s.p_OI
        dth = log3(s.R_OI.T @ run.gt_R[i])  # body-frame error, matches the covariance convention
        P = s.covariance
        P_th_O = s.R_OI @ P[0:3, 0:3] @ s.R_OI.T
        rows.append(
            [s.t_cam_ns * 1e-9, *dp, *(s.R_OI @ dth),
             float(dp @ np.linalg.solve(P[3:6, 3:6], dp)), float(dth @ np.linalg.solve(P[0:3, 0:3], dth)),
             *np.sqrt(np.diag(P)[3:6]), *np.sqrt(np.diag(P_th_O))]
        )
    return np.asarray(rows, dtype=float).reshape(-1, len(FRAME_COLUMNS))


def evaluate(run: SimRun, snaps: list) -> dict:
    """RMSE (position m, orientation deg) and NEES against the true state at camera times."""
    E = frame_errors(run, snaps)
    if E.shape[0] == 0:
        return {"frames_evaluated": 0}
    ep = np.sum(E[:, 1:4] ** 2, axis=1)
    eo = np.sum(E[:, 4:7] ** 2, axis=1)
    nees_p, nees_o = E[:, 7], E[:, 8]
    return {
        "frames_evaluated": int(E.shape[0]),
        "rmse_pos_m": float(np.sqrt(np.mean(ep))),
        "rmse_ori_deg": float(np.degrees(np.sqrt(np.mean(eo)))),
        "nees_pos": float(np.mean(nees_p)),
        "nees_ori": float(np.mean(nees_o)),
    }


# ----------------------------------------------------------------------------- CLI
def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "folder", type=Path, help="openvins_sim run folder, e.g. ../shared/data/openvins_sim/udel_gore_mono"
    )
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    p.add_argument("--out", type=Path, default=None, help="also write the JSON result to this file")
    p.add_argument(
        "--max-seconds", type=number_in(1, 1e6, unit=" s"), default=None,
        help="use only this many seconds from the start"
    )
    p.add_argument("--max-slam", type=count(0), default=None,
                   help="override max_slam (0: MSCKF features only)")
    p.add_argument("--max-msckf", type=count(0), default=None, help="override max_msckf_in_update")
    p.add_argument(
        "--min-clone-spacing", type=number, default=None,
        help="override min_clone_spacing_s (s; 0: every frame keeps its clone, as OpenVINS)",
    )
    p.add_argument(
        "--seeds",
        type=count(0),
        default=0,
        help="run N times with feature-order tie-break seeds 0..N-1 and print the median and range "
        "(single runs move with the order in which equal-length tracks compete; 0: one run, database "
        "order)",
    )
    p.add_argument("--seed", type=count(0), default=None,
                   help="one run with this feature-order tie-break seed")
    p.add_argument(
        "--jobs", type=count(1), default=1, help="parallel processes for --seeds (their timings then overlap)"
    )
    p.add_argument(
        "--frames-csv",
        type=Path,
        default=None,
        help="write per-frame errors, NEES and standard deviations of the (first) run to this CSV",
    )
    p.add_argument(
        "--perturb-init",
        action="store_true",
        help="start each run from the true state plus an error drawn from the filter's initial covariance "
        "(seeded by the run's seed, 0 without one): the Monte-Carlo protocol under which a consistent "
        "filter's NEES averages 3; OpenVINS's figures start exactly at the truth",
    )
    p.add_argument(
        "--slam-max-chi2-failures",
        type=_optional_count,
        default=argparse.SUPPRESS,
        metavar="N|none",
        help="override slam_max_chi2_failures: a SLAM landmark leaves the state after more than N chi-square "
        "rejections (OpenVINS 2.7: 1); none: a rejection drops only that observation",
    )
    p.add_argument(
        "--slam-rep",
        choices=("global_3d", "anchored_inverse_depth"),
        default=None,
        help="override the SLAM landmark representation (default: the folder's feat_rep_slam)",
    )


def _optional_count(text: str) -> int | None:
    """argparse type: a count >= 0, or 'none'."""
    if text.strip().lower() == "none":
        return None
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a count or 'none', got {text!r}") from None
    if n < 0:
        raise argparse.ArgumentTypeError(f"expected a count >= 0, got {n}")
    return n


_SIM: SimRun | None = None  # the loaded folder, shared with --jobs worker processes (fork)


def _config(sim: SimRun, args: argparse.Namespace) -> object:
    cfg = sim.config
    if args.max_slam is not None:
        cfg = cfg.updated(max_slam=args.max_slam)
    if args.max_msckf is not None:
        cfg = cfg.updated(max_msckf_in_update=args.max_msckf)
    if args.min_clone_spacing is not None:
        cfg = cfg.updated(min_clone_spacing_s=args.min_clone_spacing)
    if args.slam_rep is not None:
        cfg = cfg.updated(slam_representation=args.slam_rep)
    if getattr(args, "slam_max_chi2_failures", "default") != "default":
        cfg = cfg.updated(slam_max_chi2_failures=args.slam_max_chi2_failures)
    return cfg


def _one_run(job: tuple) -> tuple[dict, np.ndarray]:
    """One filter run on the loaded folder, job = (config, seed of the initial-state error or None):
    (figures, per-frame errors)."""
    sim = _SIM
    cfg, perturb_seed = job
    init = None if perturb_seed is None else perturbed_init(sim.init, cfg, perturb_seed)
    t_start = time.perf_counter()
    snaps, report = run_filter(sim, cfg, init=init)
    wall = time.perf_counter() - t_start
    res = evaluate(sim, snaps)
    res["ms_per_frame"] = report["ms_per_frame"]
    res["cpu_ms_per_frame"] = report["cpu_ms_per_frame"]
    res["wall_s"] = wall
    res["frames"] = report["frames_processed"]
    res["divergence_resets"] = report["divergence_resets"]
    res["feature_order_seed"] = getattr(cfg, "feature_order_seed", None)
    res["init_perturbation_seed"] = perturb_seed
    return res, frame_errors(sim, snaps)


def _seed_summary(runs: list[dict]) -> dict:
    """Median and (min, max) over runs of every figure; for NEES also the mean over runs (`<key>_mean`,
    the Monte-Carlo NEES, which a consistent filter started by `--perturb-init` keeps near 3)."""
    keys = ("rmse_pos_m", "rmse_ori_deg", "nees_pos", "nees_ori", "ms_per_frame", "cpu_ms_per_frame")
    out: dict = {}
    for k in keys:
        vals = np.array([r[k] for r in runs if k in r], dtype=float)
        if vals.size:
            out[k] = float(np.median(vals))
            out[k + "_range"] = [float(vals.min()), float(vals.max())]
            if k.startswith("nees"):
                out[k + "_mean"] = float(np.mean(vals))
    return out


def run(args: argparse.Namespace) -> int:
    global _SIM
    from runtime.errors import ConfigError

    if args.seeds > 0 and args.seed is not None:
        raise ConfigError("--seed picks one run, --seeds runs seeds 0..N-1: give one of them")
    _SIM = sim = load_sim_folder(args.folder, args.max_seconds)     # its DataError names the file
    cfg = _config(sim, args)
    if args.seeds > 0:
        cfgs = [cfg.updated(feature_order_seed=k) for k in range(args.seeds)]
    else:
        cfgs = [cfg.updated(feature_order_seed=args.seed) if args.seed is not None else cfg]
    jobs = [(c, (c.feature_order_seed or 0) if args.perturb_init else None) for c in cfgs]
    t_start = time.perf_counter()
    if args.jobs > 1 and len(cfgs) > 1:
        import multiprocessing as mp

        with mp.get_context("fork").Pool(min(args.jobs, len(cfgs))) as pool:
            outs = pool.map(_one_run, jobs)
    else:
        outs = [_one_run(j) for j in jobs]
    wall = time.perf_counter() - t_start
    runs = [r for r, _ in outs]
    if args.frames_csv is not None:
        np.savetxt(args.frames_csv, outs[0][1], delimiter=",", header=",".join(FRAME_COLUMNS), fmt="%.15g")
    if args.seeds > 0:
        per_run = ("feature_order_seed", "init_perturbation_seed", "divergence_resets")
        res = {**{k: v for k, v in runs[0].items() if k not in per_run}, **_seed_summary(runs)}
        res["divergence_resets"] = int(sum(r.get("divergence_resets", 0) for r in runs))
        res["seeds"] = runs
        res["wall_s"] = wall
    else:
        res = runs[0]
    res["folder"] = str(args.folder)
    res["perturb_init"] = bool(args.perturb_init)
    res["config"] = {
        k: getattr(cfg, k)
        for k in (
            "max_clones",
            "min_clone_spacing_s",
            "max_slam",
            "slam_representation",
            "max_slam_in_update",
            "max_msckf_in_update",
            "dt_slam_delay",
            "use_fej",
        )
    }
    res["openvins"] = sim.openvins
    if args.out is not None:
        args.out.write_text(strict_dumps(res, indent=2))
    if args.json:
        print(strict_dumps(res))
        return 0
    ov = sim.openvins
    n_runs = f"median [min-max] over tie-break seeds 0..{args.seeds - 1}, " if args.seeds > 0 else ""
    if args.perturb_init:
        n_runs += "started off the truth by a draw from the initial covariance, "
    print(
        f"openvins-sim on {args.folder} ({res.get('frames_evaluated', 0)} frames, {n_runs}wall {wall:.1f} s; "
        f"timings on a shared machine are noisy)"
    )
    print(f"{'metric':<16}{'DAVIO':>12}{'OpenVINS':>12}" + (f"{'DAVIO range':>20}" if args.seeds > 0 else ""))
    for key, fmt in (
        ("rmse_pos_m", "{:.3f}"),
        ("rmse_ori_deg", "{:.3f}"),
        ("nees_pos", "{:.2f}"),
        ("nees_ori", "{:.2f}"),
        ("ms_per_frame", "{:.2f}"),
        ("cpu_ms_per_frame", "{:.2f}"),
    ):
        ours = fmt.format(res[key]) if key in res else "-"
        theirs = fmt.format(ov[key]) if key in ov else "-"
        rng = ""
        if args.seeds > 0 and key + "_range" in res:
            lo, hi = res[key + "_range"]
            rng = f"{fmt.format(lo)}-{fmt.format(hi)}".rjust(20)
        print(f"{key:<16}{ours:>12}{theirs:>12}{rng}")
        if key + "_mean" in res:
            print(f"{key + ' mean':<16}{fmt.format(res[key + '_mean']):>12}{'':>12}")
    resets = sum(r["divergence_resets"] for r in runs)
    print(f"divergence resets: {resets}; ms_per_frame is wall clock inside "
          "the filter, cpu_ms_per_frame its thread's CPU time (less sensitive to other load); OpenVINS: wall "
          "clock")
    return 0
