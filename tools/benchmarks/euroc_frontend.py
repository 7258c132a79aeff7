"""`davio bench euroc-frontend [DIR]`: the MSCKF front-end on real EuRoC images and IMU.

On an EuRoC folder (default: ../shared/data/euroc/V1_01_easy_head, 95 still frames + the full IMU):
KLT tracks per frame (mean / min), tracker milliseconds per frame, and the static initializer's
roll/pitch error (angle between estimated and true 'up' in the IMU frame) in both modes:

- ``jerk`` (OpenVINS EuRoC: still, then an IMU jerk; IMU only, because the head's images end
  before the drone moves);
- ``still`` (initialize once a full window is still; IMU + track disparity).

Ground truth: ``full_sequence_vicon2gt.csv`` (OpenVINS authors' recomputation) and the original
``data.csv`` are both reported when present. The dynamic initializer is fed too and its verdict
(on a still platform it must refuse) is printed.

With ``--dynamic [DIR]`` (default ../shared/data/euroc_imu_gt/V1_02_medium): windows every 10 s along
a real EuRoC IMU stream, with images rendered (textured box room, EuRoC cam0 model with distortion)
at the ground-truth camera poses, tracked by the KLT tracker and fed to the dynamic initializer:
time to initialize, gravity (roll/pitch) and body-frame velocity errors against the ground truth.
Caveat: the original EuRoC V1 orientation ground truth is known to be off by up to a few degrees
(see the static figures), which bounds what the gravity error can show.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from runtime.json_out import strict_dumps
from tools.cli_types import count

NAME = "euroc-frontend"
HELP = "KLT tracks per frame, tracker ms/frame and static-init roll/pitch error on real EuRoC data"

_DEFAULT = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "euroc" / "V1_01_easy_head"
_IMU_AFTER_FRAMES_S = 10.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("path", nargs="?", default=str(_DEFAULT), help="EuRoC sequence folder (or its mav0)")
    p.add_argument(
        "--equalization",
        default="histogram",
        choices=("histogram", "clahe", "none"),
        help="tracker contrast normalisation",
    )
    p.add_argument(
        "--dynamic",
        nargs="?",
        const=str(_DYN_DEFAULT),
        default=None,
        metavar="DIR",
        help="also run the dynamic initializer on real IMU + rendered images along the ground truth "
        "of an euroc_imu_gt folder (default V1_02_medium)",
    )
    p.add_argument("--windows", type=count(1), default=8, help="dynamic: number of start windows, 10 s apart")
    p.add_argument("--attempt-every", type=count(1), default=5,
                   help="dynamic: try to initialize every N frames")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")


def _up_error_deg(gt, t_ns: int, up_est: np.ndarray) -> tuple[float, float]:
    """(angle between estimated and true up in I, |dt| to the closest ground-truth row in s)."""
    from runtime.msckf.init_common import gravity_angle_deg

    k = int(np.argmin(np.abs(gt.t_ns - t_ns)))
    return gravity_angle_deg(up_est, gt.R[k][2, :]), abs(int(gt.t_ns[k]) - t_ns) * 1e-9


def run(args: argparse.Namespace) -> int:
    from drivers import EurocDriver, Frame, ImuSample
    from runtime.msckf.init_dynamic import DynamicInitializer
    from runtime.msckf.init_static import StaticInitConfig, StaticInitializer
    from runtime.msckf.tracker import KltTracker, TrackerConfig

    driver = EurocDriver(args.path)             # its DataError names the file
    rig = driver.rig
    tracker = KltTracker(rig.camera, TrackerConfig(equalization=args.equalization))
    jerk = StaticInitializer(StaticInitConfig(wait_for_jerk=True))
    still = StaticInitializer(StaticInitConfig(wait_for_jerk=False))
    T_IC = rig.T_IC if rig.T_IC is not None else np.eye(4)
    offset = float(rig.time_offset_s or 0.0)
    dynamic = DynamicInitializer(rig.camera, T_IC, imu_noise=rig.imu, time_offset_s=offset)
    results: dict[str, object] = {"jerk": None, "still": None}
    counts: list[int] = []
    times_ms: list[float] = []
    last_frame_ns: int | None = None
    dynamic_result = None
    imu_count = 0
    for ev in driver.events():
        if isinstance(ev, ImuSample):
            imu_count += 1
            if last_frame_ns is not None and ev.t_ns > last_frame_ns + 100_000_000:
                # past the images: keep feeding only while a static mode is still undecided
                if all(r is not None for r in results.values()):
                    break
                if ev.t_ns > last_frame_ns + int(_IMU_AFTER_FRAMES_S * 1e9):
                    break
            for name, init in (("jerk", jerk), ("still", still)):
                if results[name] is None:
                    init.feed_imu(ev)
                    if imu_count % 4 == 0:  # try at 50 Hz
                        results[name] = init.try_initialize()
            dynamic.feed_imu(ev)
        elif isinstance(ev, Frame):
            t0 = time.perf_counter()
            tr = tracker.track(ev)
            times_ms.append((time.perf_counter() - t0) * 1e3)
            counts.append(len(tr))
            last_frame_ns = ev.t_ns
            t_imu = ev.t_ns + int(round(offset * 1e9))
            if results["still"] is None:
                still.feed_tracks(t_imu, tr.ids, tr.uv)
            dynamic.feed_tracks(ev.t_ns, tr.ids, tr.uv)
            if dynamic_result is None:
                dynamic_result = dynamic.try_initialize()

    out: dict[str, object] = {
        "sequence": str(args.path),
        "frames": len(counts),
        "tracks_per_frame_mean": float(np.mean(counts)) if counts else 0.0,
        "tracks_per_frame_min": int(np.min(counts)) if counts else 0,
        "tracker_ms_per_frame_mean": float(np.mean(times_ms)) if times_ms else 0.0,
        "tracker_ms_per_frame_median": float(np.median(times_ms)) if times_ms else 0.0,
        "tracker_report": tracker.report(),
        "equalization": args.equalization,
        "dynamic_init": "initialized" if dynamic_result is not None else dynamic.last_reason,
        "dynamic_rejections": dynamic.report()["rejections"],
    }
    mav0 = Path(driver.mav0)
    gts = {}
    for label, fname in (("vicon2gt", "full_sequence_vicon2gt.csv"), ("euroc_gt", "data.csv")):
        if (mav0 / "state_groundtruth_estimate0" / fname).is_file():
            gts[label] = EurocDriver(args.path, groundtruth_file=fname).groundtruth()
    for mode, res in results.items():
        entry: dict[str, object] = {"initialized": res is not None}
        init = jerk if mode == "jerk" else still
        if res is None:
            entry["reason"] = init.last_reason
        else:
            entry["t_ns"] = int(res.t_ns)
            entry["bg"] = [float(x) for x in res.bg]
            entry["ba"] = [float(x) for x in res.ba]
            for label, gt in gts.items():
                if gt is None or len(gt) == 0:
                    continue
                err, dt = _up_error_deg(gt, res.t_ns, res.gravity_in_imu)
                if dt < 0.05:
                    entry[f"roll_pitch_err_deg_{label}"] = err
        out[f"static_{mode}"] = entry
    driver.close()
    if args.dynamic is not None:
        out["dynamic"] = run_dynamic(Path(args.dynamic), 10.0, args.windows, args.attempt_every)

    if args.json:
        print(strict_dumps(out))
        return 0
    print(f"EuRoC front-end on {args.path}")
    print(f"{'frames':<40}{out['frames']}")
    mean, low = out["tracks_per_frame_mean"], out["tracks_per_frame_min"]
    print(f"{'tracks/frame mean | min':<40}{mean:.1f} | {low}")
    print(
        f"{'tracker ms/frame mean | median':<40}{out['tracker_ms_per_frame_mean']:.2f} | "
        f"{out['tracker_ms_per_frame_median']:.2f}   (2 shared cores: noisy)"
    )
    for mode in ("jerk", "still"):
        e = out[f"static_{mode}"]
        if not e["initialized"]:
            print(f"{'static init (' + mode + ')':<40}not initialized: {e['reason']}")
            continue
        errs = ", ".join(
            f"{k.removeprefix('roll_pitch_err_deg_')} {v:.3f} deg"
            for k, v in e.items()
            if k.startswith("roll_pitch_err_deg_")
        )
        print(f"{'static init (' + mode + ') roll/pitch err':<40}{errs}")
    print(f"{'dynamic init':<40}{out['dynamic_init']}")
    print(f"{'dynamic init rejections':<40}{out['dynamic_rejections']}")
    if "dynamic" in out:
        dyn = out["dynamic"]
        print(f"\nDynamic init, real IMU + rendered room along the ground truth of {dyn['sequence']}")
        print(f"{'start s':>8} {'init':>5} {'T s':>6} {'grav deg':>9} {'vel m/s':>8} {'|v| m/s':>8}  reason")
        for r in dyn["rows"]:
            if r["initialized"]:
                print(
                    f"{r['start_s']:8.1f} {'yes':>5} {r['time_to_init_s']:6.2f} {r['gravity_err_deg']:9.3f} "
                    f"{r['velocity_err_mps']:8.3f} {r['speed_true_mps']:8.3f}"
                )
            else:
                print(f"{r['start_s']:8.1f} {'no':>5} {'':>6} {'':>9} {'':>8} {'':>8}  {r['reason']}")
        print(
            f"moving-camera tracking: min {dyn['tracks_per_frame_min']} tracks/frame, "
            f"{dyn['tracker_ms_mean']:.2f} ms/frame mean (rendered 752x480 images)"
        )
        if dyn["initialized"]:
            print(
                f"initialized {dyn['initialized']}/{dyn['windows']}; median gravity error "
                f"{dyn['gravity_err_deg_median']:.3f} deg, velocity error "
                f"{dyn['velocity_err_mps_median']:.3f} m/s, time to init {dyn['time_to_init_s_median']:.2f} s"
            )
    return 0


# ----------------------------------------------------------------------------- dynamic init on real IMU
_DYN_DEFAULT = (
    Path(__file__).resolve().parents[2].parent / "shared" / "data" / "euroc_imu_gt" / "V1_02_medium"
)
ROOM_MIN = np.array([-4.5, -4.0, 0.0])
"""Lower corner of the rendered textured box room (EuRoC Vicon-room world frame), m."""
ROOM_MAX = np.array([4.5, 5.5, 4.0])
"""Upper corner of the rendered room, m."""
_TEXEL_M = 0.006
_TEX_SIZE = 2048


def _room_textures(seed: int = 7) -> list[np.ndarray]:
    """Six band-limited multi-scale random textures (float32), one per wall."""
    import cv2

    rng = np.random.default_rng(seed)
    out = []
    for _ in range(6):
        tex = np.zeros((_TEX_SIZE, _TEX_SIZE), np.float32)
        for cell, weight in ((64, 1.0), (16, 0.6), (6, 0.4)):
            coarse = rng.uniform(0, 1, (_TEX_SIZE // cell, _TEX_SIZE // cell)).astype(np.float32)
            tex += weight * cv2.resize(coarse, (_TEX_SIZE, _TEX_SIZE), interpolation=cv2.INTER_CUBIC)
        tex = cv2.GaussianBlur(tex, (0, 0), 2.0)
        out.append(((tex - tex.min()) / (tex.max() - tex.min()) * 220 + 20).astype(np.float32))
    return out


def render_room(
    rays_C: np.ndarray, R_WC: np.ndarray, p_WC: np.ndarray, textures: list[np.ndarray]
) -> np.ndarray:
    """uint8 image of the textured box room along per-pixel camera rays (H, W, 3) at pose (R_WC, p_WC)."""
    import cv2

    d = rays_C @ R_WC.T
    best_t = np.full(d.shape[:2], np.inf)
    img = np.zeros(d.shape[:2], np.float32)
    c = _TEX_SIZE / 2
    for axis in range(3):
        for side, bound in enumerate((ROOM_MIN[axis], ROOM_MAX[axis])):
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (bound - p_WC[axis]) / d[..., axis]
            t = np.where(t > 1e-6, t, np.inf)
            closer = t < best_t
            if not closer.any():
                continue
            best_t = np.where(closer, t, best_t)
            P = p_WC + d * np.where(np.isfinite(t), t, 0.0)[..., None]
            a, b = [k for k in range(3) if k != axis]
            mx = (c + P[..., a] / _TEXEL_M).astype(np.float32)
            my = (c + P[..., b] / _TEXEL_M).astype(np.float32)
            sample = cv2.remap(
                textures[2 * axis + side], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT
            )
            img = np.where(closer, sample, img)
    return np.clip(img, 0, 255).astype(np.uint8)


def run_dynamic(
    folder: Path, window_s: float, max_windows: int, attempt_every: int, config: object | None = None
) -> dict:
    """Windows every `window_s` along the real IMU: rendered images -> tracker -> dynamic initializer.

    Each window starts a fresh tracker and DynamicInitializer (config: DynamicInitConfig or None),
    renders the textured box room through the EuRoC cam0 model (with its distortion) at the ground-truth
    camera poses and real camera stamps, feeds the REAL IMU, and tries to initialize every
    `attempt_every` frames until it succeeds or the window ends.
    """
    from calib import euroc_rig
    from drivers import Frame, ImuSample, read_camera_timestamps, read_euroc_groundtruth, read_euroc_imu_csv
    from runtime.geometry import interpolate_poses
    from runtime.msckf.init_common import gravity_angle_deg
    from runtime.msckf.init_dynamic import DynamicInitializer
    from runtime.msckf.tracker import KltTracker

    rig = euroc_rig()
    cam = rig.camera
    t_imu, gyro, accel = read_euroc_imu_csv(folder / "imu0.csv")
    t_cam = read_camera_timestamps(folder / "cam0_timestamps.txt")
    gt = read_euroc_groundtruth(folder / "groundtruth.csv")
    u, v = np.meshgrid(np.arange(cam.width, dtype=np.float64), np.arange(cam.height, dtype=np.float64))
    rays_C = cam.unproject(np.stack([u, v], axis=-1))
    textures = _room_textures()
    R_IC, p_IC = rig.T_IC[:3, :3], rig.T_IC[:3, 3]
    t_cam = t_cam[(t_cam > gt.t_ns[0]) & (t_cam < gt.t_ns[-1]) & (t_cam > t_imu[0]) & (t_cam < t_imu[-1])]
    starts = np.arange(t_cam[0] + 1_000_000_000, t_cam[-1] - int(window_s * 1e9), int(window_s * 1e9))
    rows = []
    for s in starts[:max_windows]:
        tracker = KltTracker(cam)
        init = DynamicInitializer(cam, rig.T_IC, config, imu_noise=rig.imu)
        frames = t_cam[(t_cam >= s) & (t_cam < s + int(window_s * 1e9))]
        poses = interpolate_poses(gt, frames)
        k_imu = int(np.searchsorted(t_imu, s - 50_000_000))
        res = None
        ms: list[float] = []
        track_ms: list[float] = []
        counts: list[int] = []
        for j, tf in enumerate(frames):
            while k_imu < t_imu.size and t_imu[k_imu] <= tf + 10_000_000:
                init.feed_imu(ImuSample(int(t_imu[k_imu]), gyro[k_imu], accel[k_imu]))
                k_imu += 1
            R_WI, p_WI = poses.R[j], poses.p[j]
            img = render_room(rays_C, R_WI @ R_IC, p_WI + R_WI @ p_IC, textures)
            t_track = time.perf_counter()
            tr = tracker.track(Frame(int(tf), img))
            track_ms.append((time.perf_counter() - t_track) * 1e3)
            counts.append(len(tr))
            init.feed_tracks(tr.t_ns, tr.ids, tr.uv)
            if j % attempt_every == 0:
                t0 = time.perf_counter()
                res = init.try_initialize()
                ms.append((time.perf_counter() - t0) * 1e3)
                if res is not None:
                    break
        row: dict[str, object] = {"start_s": (int(s) - int(t_cam[0])) * 1e-9, "initialized": res is not None}
        if res is None:
            row["reason"] = init.last_reason
        else:
            truth = interpolate_poses(gt, np.array([res.t_ns]))
            R_true, v_true = truth.R[0], truth.v[0]
            row["time_to_init_s"] = (res.t_ns - int(s)) * 1e-9
            row["gravity_err_deg"] = gravity_angle_deg(res.gravity_in_imu, R_true[2, :])
            row["velocity_err_mps"] = float(np.linalg.norm(res.R_OI.T @ res.v_OI - R_true.T @ v_true))
            row["speed_true_mps"] = float(np.linalg.norm(v_true))
            row["bg_err"] = float(np.linalg.norm(res.bg - truth.bg[0])) if truth.bg is not None else None
        row["attempt_ms_max"] = max(ms) if ms else 0.0
        row["tracks_per_frame_min"] = min(counts) if counts else 0
        row["tracker_ms_mean"] = float(np.mean(track_ms)) if track_ms else 0.0
        rows.append(row)
    ok = [r for r in rows if r["initialized"]]
    return {
        "sequence": str(folder),
        "windows": len(rows),
        "initialized": len(ok),
        "gravity_err_deg_median": float(np.median([r["gravity_err_deg"] for r in ok])) if ok else None,
        "velocity_err_mps_median": float(np.median([r["velocity_err_mps"] for r in ok])) if ok else None,
        "time_to_init_s_median": float(np.median([r["time_to_init_s"] for r in ok])) if ok else None,
        "tracks_per_frame_min": min((r["tracks_per_frame_min"] for r in rows), default=0),
        "tracker_ms_mean": float(np.mean([r["tracker_ms_mean"] for r in rows])) if rows else 0.0,
        "rows": rows,
    }
