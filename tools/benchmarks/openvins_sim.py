"""`davio bench openvins-sim DIR`: our MSCKF on the OpenVINS simulator's measurements.

The folder (shared/data/openvins_sim/<run>, see its README) holds the IMU samples and feature tracks that
OpenVINS itself was fed, the true state at camera times, the true calibration and initial state
(sim_info.txt), OpenVINS's configuration files and its own per-frame result. We run our filter on the same
inputs, initialised from the same true state with the equivalent configuration, and print position /
orientation RMSE, NEES and ms per frame beside OpenVINS's figures.
"""

from __future__ import annotations

import argparse
import gzip
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from runtime.json_out import strict_dumps

NAME = "openvins-sim"
HELP = "our MSCKF on the OpenVINS simulator's IMU samples and feature tracks, beside OpenVINS's result"


# ----------------------------------------------------------------------------- reading the folder
def _open_text(folder: Path, name: str) -> str:
    """Contents of name or name.gz in folder."""
    from runtime.errors import DataError

    for cand in (folder / name, folder / (name + ".gz")):
        if cand.exists():
            if cand.suffix == ".gz":
                with gzip.open(cand, "rt") as f:
                    return f.read()
            return cand.read_text()
    raise DataError(f"missing {name}[.gz]", folder / name)


def seconds_to_ns(token: str) -> int:
    """Exact int ns from a decimal seconds string (no float rounding)."""
    neg = token.startswith("-")
    tok = token.lstrip("+-")
    whole, _, frac = tok.partition(".")
    ns = int(whole or "0") * 1_000_000_000 + int((frac + "000000000")[:9])
    return -ns if neg else ns


def _table(folder: Path, name: str, ncols: int) -> tuple[np.ndarray, np.ndarray]:
    """(t_ns (n,), values (n, ncols-1)) of a whitespace table with '#' comments."""
    from runtime.errors import DataError

    text = _open_text(folder, name)
    times: list[int] = []
    rows: list[str] = []
    cache: dict[str, int] = {}
    for lineno, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        tok, _, rest = s.partition(" ")
        if len(s.split()) != ncols:
            raise DataError(f"expected {ncols} columns, got {len(s.split())}", folder / name, lineno)
        t = cache.get(tok)
        if t is None:
            t = seconds_to_ns(tok)
            cache[tok] = t
        times.append(t)
        rows.append(rest)
    vals = np.array(" ".join(rows).split(), dtype=float).reshape(len(rows), ncols - 1)
    return np.asarray(times, dtype=np.int64), vals


def jpl_to_R_OI(q_xyzw: np.ndarray) -> np.ndarray:
    """JPL q_GtoI (x, y, z, w) -> R_OI = R_GtoI^T; (..., 4) -> (..., 3, 3)."""
    q = np.asarray(q_xyzw, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    v, w = q[..., :3], q[..., 3]
    I3 = np.eye(3)
    S = np.zeros(q.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2], S[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    S[..., 1, 0], S[..., 2, 0], S[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    R_GtoI = (
        (2 * w[..., None, None] ** 2 - 1) * I3
        - 2 * w[..., None, None] * S
        + 2 * v[..., :, None] * v[..., None, :]
    )
    return np.swapaxes(R_GtoI, -1, -2)


def _read_yaml(path: Path) -> dict:
    import yaml

    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith("%YAML")]
    return yaml.safe_load("\n".join(lines)) or {}


@dataclass
class SimRun:
    """Everything the benchmark needs from one simulator folder."""

    rig: object
    config: object
    init: tuple  # (t_ns, R_OI, p, v, bg, ba)
    imu_t: np.ndarray
    imu_w: np.ndarray
    imu_a: np.ndarray
    feat_t: np.ndarray  # (K,) frame times
    feat_slices: list  # per frame: (ids, uv)
    gt_t: np.ndarray
    gt_R: np.ndarray
    gt_p: np.ndarray
    true_calib: tuple  # (R_IC, p_IC, time_offset_s)
    openvins: dict  # OpenVINS's own figures (may be empty)


def load_sim_folder(folder: Path, max_seconds: float | None = None) -> SimRun:
    """Read an openvins_sim folder (plain or gzipped files)."""
    from calib import ImuNoise, PinholeRadtan, Rig
    from runtime.errors import DataError
    from runtime.msckf.config import MsckfConfig

    folder = Path(folder)
    info = {}
    for line in _open_text(folder, "sim_info.txt").splitlines():
        parts = line.split()
        if parts:
            info.setdefault(parts[0], []).append(parts)
    try:
        cam = info["cam0"]
        intr = [p for p in cam if p[1] == "w"][0]
        ext = [p for p in cam if p[1].startswith("extrinsics")][0]
        w, h = int(intr[2]), int(intr[4])
        nums = [float(x) for x in intr[-8:]]
        camera = PinholeRadtan(w, h, *nums[:4], distortion=nums[4:8])
        e = [float(x) for x in ext[-7:]]
        R_CI = np.swapaxes(jpl_to_R_OI(np.array(e[:4])), 0, 1)  # q_ItoC JPL -> R_ItoC
        p_IinC = np.array(e[4:7])
        R_IC = R_CI.T
        p_IC = -R_IC @ p_IinC
        t_d = float(info["calib_camimu_dt"][0][1])
        g_mag = float(info["gravity_mag"][0][1])
        init = info["init_with_gt"][0]
        vals = init[init.index("imustate(t,q,p,v,bg,ba)") + 1 :]
        t0 = seconds_to_ns(vals[0])
        x0 = np.array([float(v) for v in vals[1:17]])
    except (KeyError, IndexError, ValueError) as exc:
        raise DataError(f"cannot parse sim_info.txt: {exc}", folder / "sim_info.txt") from exc
    T_IC = np.eye(4)
    T_IC[:3, :3], T_IC[:3, 3] = R_IC, p_IC
    kal = _read_yaml(folder / "kalibr_imu_chain.yaml").get("imu0", {})
    noise = ImuNoise(
        kal.get("gyroscope_noise_density"),
        kal.get("gyroscope_random_walk"),
        kal.get("accelerometer_noise_density"),
        kal.get("accelerometer_random_walk"),
        kal.get("update_rate"),
    )
    rig = Rig(camera=camera, T_IC=T_IC, time_offset_s=t_d, imu=noise, name=folder.name)
    est = _read_yaml(folder / "openvins_estimator_config.yaml")
    cfg = MsckfConfig(gravity_mag=g_mag).with_imu_noise(noise)
    mapping = {
        "use_fej": "use_fej",
        "max_clones": "max_clones",
        "max_slam": "max_slam",
        "max_slam_in_update": "max_slam_in_update",
        "max_msckf_in_update": "max_msckf_in_update",
        "dt_slam_delay": "dt_slam_delay",
        "up_msckf_sigma_px": "sigma_pix",
        "up_msckf_chi2_multipler": "chi2_multiplier",
        "calib_cam_extrinsics": "calib_extrinsics",
        "calib_cam_timeoffset": "calib_time_offset",
        "calib_cam_intrinsics": "calib_intrinsics",
        "try_zupt": "try_zupt",
        "zupt_chi2_multipler": "zupt_chi2_multiplier",
        "zupt_max_velocity": "zupt_max_velocity",
        "zupt_noise_multiplier": "zupt_noise_multiplier",
        "zupt_max_disparity": "zupt_max_disparity",
    }
    kw = {ours: est[theirs] for theirs, ours in mapping.items() if theirs in est}
    reps = {"GLOBAL_3D": "global_3d", "ANCHORED_MSCKF_INVERSE_DEPTH": "anchored_inverse_depth"}
    if "feat_rep_slam" in est:
        if str(est["feat_rep_slam"]) not in reps:
            raise DataError(
                f"feat_rep_slam {est['feat_rep_slam']!r} is not supported (use one of {list(reps)})",
                folder / "openvins_estimator_config.yaml",
            )
        kw["slam_representation"] = reps[str(est["feat_rep_slam"])]
    cfg = cfg.updated(**kw)
    R0 = jpl_to_R_OI(x0[0:4])
    init_state = (t0, R0, x0[4:7], x0[7:10], x0[10:13], x0[13:16])
    imu_t, imu = _table(folder, "imu.csv", 7)
    ft, fv = _table(folder, "cam_feats.csv", 5)
    if np.any(fv[:, 0] != 0):
        keep = fv[:, 0] == 0
        ft, fv = ft[keep], fv[keep]
    gt_t, gt = _table(folder, "gt_cam.csv", 17)
    if max_seconds is not None:
        t_end = t0 + int(max_seconds * 1e9)
        imu_t, imu = imu_t[imu_t <= t_end + 50_000_000], imu[imu_t <= t_end + 50_000_000]
        keep = ft <= t_end
        ft, fv = ft[keep], fv[keep]
    bounds = np.flatnonzero(np.diff(ft)) + 1
    starts = np.r_[0, bounds]
    ends = np.r_[bounds, ft.size]
    slices = [(fv[a:b, 1].astype(np.int64), fv[a:b, 2:4]) for a, b in zip(starts, ends, strict=True)]
    openvins: dict = {}
    summary = folder / "openvins_summary.txt"
    if summary.exists():
        import re

        txt = summary.read_text()
        m = re.search(r"RMSE:\s*([\d.]+)\s*\(deg\) orientation,\s*([\d.]+)\s*\(m\) position", txt)
        if m:
            openvins["rmse_ori_deg"], openvins["rmse_pos_m"] = float(m.group(1)), float(m.group(2))
        m = re.search(r"NEES:\s*([\d.]+)\s*orientation,\s*([\d.]+)\s*position", txt)
        if m:
            openvins["nees_ori"], openvins["nees_pos"] = float(m.group(1)), float(m.group(2))
        m = re.search(r"mean=([\d.]+) ms", txt)
        if m:
            openvins["ms_per_frame"] = float(m.group(1))
    return SimRun(
        rig,
        cfg,
        init_state,
        imu_t,
        imu[:, 0:3],
        imu[:, 3:6],
        ft[starts],
        slices,
        gt_t,
        jpl_to_R_OI(gt[:, 0:4]),
        gt[:, 4:7],
        (R_IC, p_IC, t_d),
        openvins,
    )


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
        "--max-seconds", type=float, default=None, help="use only this many seconds from the start"
    )
    p.add_argument("--max-slam", type=int, default=None, help="override max_slam (0: MSCKF features only)")
    p.add_argument("--max-msckf", type=int, default=None, help="override max_msckf_in_update")
    p.add_argument(
        "--min-clone-spacing", type=float, default=None,
        help="override min_clone_spacing_s (s; 0: every frame keeps its clone, as OpenVINS)",
    )
    p.add_argument(
        "--seeds",
        type=int,
        default=0,
        help="run N times with feature-order tie-break seeds 0..N-1 and print the median and range "
        "(single runs move with the order in which equal-length tracks compete; 0: one run, database "
        "order)",
    )
    p.add_argument("--seed", type=int, default=None, help="one run with this feature-order tie-break seed")
    p.add_argument(
        "--jobs", type=int, default=1, help="parallel processes for --seeds (their timings then overlap)"
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
    from runtime.errors import DavioError

    try:
        _SIM = sim = load_sim_folder(args.folder, args.max_seconds)
    except DavioError as exc:
        print(f"openvins-sim: {exc}")
        return 2
    if args.seeds < 0 or args.jobs < 1:
        print("openvins-sim: --seeds must be >= 0 and --jobs >= 1")
        return 2
    if args.seeds > 0 and args.seed is not None:
        print("openvins-sim: --seed picks one run, --seeds runs seeds 0..N-1: give one of them")
        return 2
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
