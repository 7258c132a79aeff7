"""Reading an OpenVINS simulator dump (shared/data/openvins_sim/<run>, see its README): the IMU samples and
feature tracks OpenVINS was fed, the true state at camera times, the true calibration and initial state
(sim_info.txt), OpenVINS's configuration and its own per-frame result (`davio bench openvins-sim`)."""

from __future__ import annotations

import gzip
from dataclasses import dataclass
from pathlib import Path

import numpy as np


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


_OPENVINS_TRIANGULATION = {
    "fi_max_cond_number": ("tri_max_cond", 10000.0),
    "fi_min_dist": ("tri_min_dist", 0.10),
    "fi_max_dist": ("tri_max_dist", 60.0),
    "fi_max_baseline": ("tri_max_baseline_ratio", 40.0),
}
"""OpenVINS 2.7's triangulation options: config key -> (MsckfConfig field, OpenVINS's default)."""


def openvins_triangulation(est: dict) -> dict[str, float]:
    """MsckfConfig triangulation fields from an OpenVINS estimator config, OpenVINS's own defaults
    (FeatureInitializerOptions.h) where it sets none: the comparison then runs OpenVINS's gates whatever
    ours are."""
    return {ours: float(est.get(theirs, default))
            for theirs, (ours, default) in _OPENVINS_TRIANGULATION.items()}


def load_sim_folder(folder: Path, max_seconds: float | None = None) -> SimRun:
    """Read an openvins_sim folder (plain or gzipped files)."""
    from calib import ImuNoise, PinholeRadtan, Rig
    from runtime.errors import DataError
    from runtime.msckf.config import MsckfConfig

    folder = Path(folder)
    if not folder.is_dir():
        raise DataError("is a file, not an openvins_sim run folder" if folder.exists() else
                        "no such folder (an openvins_sim run folder: sim_info.txt, imu.txt, ...)", folder)
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
    # OpenVINS 2.7's defaults where its yaml is silent (VioManagerOptions.h: every calibration off), not ours
    kw = {"calib_extrinsics": False, "calib_time_offset": False, "calib_intrinsics": False}
    kw.update({ours: est[theirs] for theirs, ours in mapping.items() if theirs in est})
    kw.update(openvins_triangulation(est))
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
