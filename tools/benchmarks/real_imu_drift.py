"""`davio bench imu-drift`: how far the real EuRoC IMU integrates from ground truth over 1 s windows.

From the ground-truth state (pose, velocity, and the ground-truth biases when groundtruth.csv has
them) at each window start, the real IMU is integrated (drivers.sim.dead_reckoning) for
`window` seconds and compared with the ground-truth pose at the window end.

`--curve` adds the drift over several window lengths (constant biases fitted over the sequence) for the real
IMU (against the ground truth as recorded, and against the IMU-consistent truth that EuRoC-trajectory
recordings render from, drivers.sim.imu_consistent) and, with `--synthetic`, for synthetic IMUs of the
named error models (drivers.sim.imu_synth.IMU_PROFILES) along the same trajectory (a spline fitted to the
ground truth), by the same protocol: how ImuErrorModel.euroc_measured was fitted and is checked.
"""

from __future__ import annotations

import argparse

import numpy as np

from tools.cli_types import number_in

NAME = "imu-drift"
HELP = ("real EuRoC IMU integrated from ground truth over 1 s windows (--curve: several lengths, beside "
        "synthetic IMUs): position/orientation drift")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--sequence",
        action="append",
        default=None,
        help="sequence under ../shared/data/euroc_imu_gt (repeatable; default V1_02_medium and MH_03_medium)",
    )
    p.add_argument(
        "--data", default=None, help="folder holding the sequences (default ../shared/data/euroc_imu_gt)"
    )
    p.add_argument("--window", type=number_in(0.001, 3600, unit=" s"), default=1.0,
                   help="integration window, s")
    p.add_argument("--step", type=number_in(0.001, 3600, unit=" s"), default=0.5,
                   help="spacing of window starts, s")
    p.add_argument("--curve", default=None, metavar="S,S,...",
                   help="also the drift over these window lengths, s (e.g. 0.25,0.5,1,2,4)")
    p.add_argument("--synthetic", default=None, metavar="PROFILE,...",
                   help="with --curve: synthetic IMUs of these error models along the same trajectory "
                        "(datasheet, euroc-measured)")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def fit_constant_biases(
    t_imu: np.ndarray, gyro: np.ndarray, accel: np.ndarray, gt, g: float = 9.81
) -> tuple[np.ndarray, np.ndarray]:
    """Constant (bg rad/s, ba m/s^2) that best explain the IMU given the ground truth.

    Medians over the whole sequence of the residuals against body rates from consecutive
    ground-truth rotations and world accelerations from second differences of positions over 50 ms.
    """
    from drivers.sim.spline import interpolate_positions, interpolate_rotations
    from runtime.geometry.so3 import so3_log

    t = gt.t_ns
    dt = np.diff(t).astype(np.float64) * 1e-9
    omega = so3_log(np.einsum("nji,njk->nik", gt.R[:-1], gt.R[1:])) / dt[:, None]
    t_mid = t[:-1] + np.diff(t) // 2
    inside = (t_imu > t_mid[0]) & (t_imu < t_mid[-1])
    bg = np.median(gyro[inside] - interpolate_positions(t_mid, omega, t_imu[inside]), axis=0)
    k = 10  # samples each side (~50 ms at 200 Hz)
    ts = (t - t[0]).astype(np.float64) * 1e-9
    h = (ts[2 * k :] - ts[: -2 * k]) / 2
    a_W = (gt.p[2 * k :] - 2 * gt.p[k:-k] + gt.p[: -2 * k]) / (h**2)[:, None]
    t_a = t[k:-k]
    inside = (t_imu > t_a[0]) & (t_imu < t_a[-1])
    R = interpolate_rotations(t, gt.R, t_imu[inside])
    f_W = interpolate_positions(t_a, a_W, t_imu[inside]) + np.array([0.0, 0.0, g])
    ba = np.median(accel[inside] - np.einsum("nji,nj->ni", R, f_W), axis=0)
    return bg, ba


def drift_windows(
    t_imu: np.ndarray,
    gyro: np.ndarray,
    accel: np.ndarray,
    gt,
    window_s: float = 1.0,
    step_s: float = 0.5,
    use_gt_bias: bool = True,
    constant_bias: tuple[np.ndarray, np.ndarray] | None = None,
) -> dict:
    """Position (m) and orientation (deg) errors after integrating each window from the true state.

    gt: PoseTrajectory T_WI (IMU clock); its v is used when present, else central differences.
    Biases: `constant_bias` when given, else gt's bg/ba when present and use_gt_bias, else zero.
    """
    from drivers.sim.dead_reckoning import integrate_imu
    from drivers.sim.sampled_motion import SampledMotion
    from drivers.sim.spline import interpolate_positions
    from runtime.geometry.so3 import so3_log

    motion = SampledMotion(gt)
    inside = (t_imu >= gt.t_ns[0]) & (t_imu <= gt.t_ns[-1])
    t_imu, gyro, accel = t_imu[inside], gyro[inside], accel[inside]
    w_ns, s_ns = int(window_s * 1e9), int(step_s * 1e9)
    pos_err, rot_err = [], []
    biased = use_gt_bias and gt.bg is not None and gt.ba is not None
    start = int(t_imu[0])
    while start + w_ns <= int(t_imu[-1]):
        i0 = int(np.searchsorted(t_imu, start))
        i1 = int(np.searchsorted(t_imu, start + w_ns, side="right"))
        sl = slice(i0, i1)
        t = t_imu[sl]
        R0, p0 = motion.pose(t[:1])
        v0 = motion.velocity(t[:1])[0]
        bg = interpolate_positions(gt.t_ns, gt.bg, t[:1])[0] if biased else None
        ba = interpolate_positions(gt.t_ns, gt.ba, t[:1])[0] if biased else None
        if constant_bias is not None:
            bg, ba = constant_bias
        R, p, _ = integrate_imu(t, gyro[sl], accel[sl], R0[0], p0[0], v0, bg, ba)
        R1, p1 = motion.pose(t[-1:])
        pos_err.append(float(np.linalg.norm(p[-1] - p1[0])))
        rot_err.append(float(np.degrees(np.linalg.norm(so3_log(R1[0].T @ R[-1])))))
        start += s_ns
    pe, re = np.array(pos_err), np.array(rot_err)
    if pe.size == 0:
        return {"windows": 0}
    label = "ground truth" if biased else "zero"
    if constant_bias is not None:
        label = "constant, fitted to ground truth"
    return {
        "windows": int(pe.size),
        "window_s": window_s,
        "biases": label,
        "velocity": "ground truth" if gt.v is not None else "central differences of positions",
        "position_m": {
            "median": float(np.median(pe)),
            "p95": float(np.percentile(pe, 95)),
            "max": float(pe.max()),
        },
        "orientation_deg": {
            "median": float(np.median(re)),
            "p95": float(np.percentile(re, 95)),
            "max": float(re.max()),
        },
    }


def drift_curve(t_imu: np.ndarray, gyro: np.ndarray, accel: np.ndarray, gt, windows: list[float],
                step_s: float) -> dict:
    """{window s: drift_windows(...)} with constant biases fitted over the sequence."""
    bias = fit_constant_biases(t_imu, gyro, accel, gt)
    return {f"{w:g}": drift_windows(t_imu, gyro, accel, gt, w, step_s, constant_bias=bias) for w in windows}


def synthetic_curve(gt, profile: str, windows: list[float], step_s: float, seed: int = 0) -> dict:
    """drift_curve of a synthetic IMU (error model `profile`) along a spline fitted to gt (0.1 s knots)."""
    from drivers.sim.imu_synth import imu_errors_for, imu_stamps, synthesize_imu
    from drivers.sim.spline import fit_pose_spline
    from runtime.geometry.trajectory import PoseTrajectory

    spline = fit_pose_spline(gt.t_ns, gt.p, gt.R, dt_s=0.1)
    t = imu_stamps(spline.t0_ns, spline.t_end_ns, 200.0)
    truth = spline.sample(t)
    imu = synthesize_imu(spline, t, imu_errors_for(profile), seed=seed)
    return drift_curve(t, imu.gyro, imu.accel, PoseTrajectory(t, truth.p, truth.R, truth.v), windows, step_s)


def _floats(spec: str, flag: str) -> list[float]:
    from runtime.errors import ConfigError

    try:
        out = [float(x) for x in spec.split(",") if x.strip()]
    except ValueError:
        raise ConfigError(f"{flag} takes comma-separated seconds, got {spec!r}") from None
    if not out or not all(np.isfinite(x) and 0.001 <= x <= 3600 for x in out):
        raise ConfigError(f"{flag} takes seconds from 0.001 to 3600, got {spec!r}")
    return out


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from drivers.euroc import read_euroc_imu_csv
    from drivers.trajectory_files import read_trajectory
    from runtime.errors import ConfigError, DataError
    from runtime.json_out import strict_dumps

    root = (
        Path(args.data)
        if args.data
        else Path(__file__).resolve().parents[2].parent / "shared" / "data" / "euroc_imu_gt"
    )
    from drivers.sim.imu_synth import IMU_PROFILES

    windows = _floats(args.curve, "--curve") if args.curve else None
    profiles = [x.strip() for x in (args.synthetic or "").split(",") if x.strip()]
    if profiles and windows is None:
        raise ConfigError("--synthetic needs --curve (the window lengths to compare over)")
    bad = [x for x in profiles if x not in IMU_PROFILES]
    if bad:
        raise ConfigError(f"--synthetic: unknown {', '.join(bad)}; choose from {', '.join(IMU_PROFILES)}")
    results = {}
    for seq in args.sequence or ["V1_02_medium", "MH_03_medium"]:
        folder = root / seq
        gt_path = folder / "groundtruth.csv"
        if not gt_path.is_file():
            gt_path = folder / "groundtruth_tum.txt"
        if not gt_path.is_file():
            raise DataError("no groundtruth.csv or groundtruth_tum.txt (is ../shared/data present?)", folder)
        gt = read_trajectory(gt_path)
        t, g, a = read_euroc_imu_csv(folder / "imu0.csv", policy="strict")
        results[seq] = {"groundtruth": gt_path.name}
        if gt.bg is not None:
            results[seq]["with_gt_bias"] = drift_windows(t, g, a, gt, args.window, args.step, True)
            results[seq]["zero_bias"] = drift_windows(t, g, a, gt, args.window, args.step, False)
        bias = fit_constant_biases(t, g, a, gt)
        results[seq]["fitted_bias"] = drift_windows(t, g, a, gt, args.window, args.step, constant_bias=bias)
        results[seq]["fitted_bias"]["bg"] = bias[0].tolist()
        results[seq]["fitted_bias"]["ba"] = bias[1].tolist()
        if windows is not None:
            from drivers.sim.imu_consistent import DEFAULT_SMOOTHING_S, imu_consistent_groundtruth

            inside = (t >= gt.t_ns[0]) & (t <= gt.t_ns[-1])
            consistent = imu_consistent_groundtruth(gt, t[inside], g[inside], DEFAULT_SMOOTHING_S)
            # against the ground truth as recorded, and against the truth the EuRoC-trajectory recordings
            # render from (what the filter faces there)
            curves = {"real": drift_curve(t, g, a, gt, windows, args.step),
                      "real, imu-consistent truth": drift_curve(t, g, a, consistent, windows, args.step)}
            for prof in profiles:
                curves[prof] = synthetic_curve(gt, prof, windows, args.step)
            results[seq]["curve"] = curves
    if args.json:
        print(strict_dumps(results))
        return 0
    from rich.console import Console
    from rich.table import Table

    tab = Table(title=f"real IMU integrated from ground truth over {args.window:g} s windows")
    for col in (
        "sequence",
        "biases",
        "velocity",
        "windows",
        "pos median m",
        "pos p95 m",
        "rot median deg",
        "rot p95 deg",
    ):
        tab.add_column(col)
    for seq, res in results.items():
        for key in ("with_gt_bias", "fitted_bias", "zero_bias"):
            r = res.get(key)
            if not r or not r.get("windows"):
                continue
            tab.add_row(
                seq,
                r["biases"],
                r["velocity"],
                str(r["windows"]),
                f"{r['position_m']['median']:.4f}",
                f"{r['position_m']['p95']:.4f}",
                f"{r['orientation_deg']['median']:.3f}",
                f"{r['orientation_deg']['p95']:.3f}",
            )
    Console().print(tab)
    for seq, res in results.items():
        if "curve" not in res:
            continue
        ct = Table(title=f"{seq}: drift over window lengths (constant biases fitted over the sequence), "
                         "position median mm / orientation median deg")
        ct.add_column("IMU")
        for w in windows:
            ct.add_column(f"{w:g} s")
        for name, curve in res["curve"].items():
            ct.add_row(name, *(f"{1e3 * c['position_m']['median']:.1f} / {c['orientation_deg']['median']:.3f}"
                               for c in curve.values()))
        Console(width=max(Console().width, 140)).print(ct)
    return 0
