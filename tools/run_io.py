"""Opening recordings and writing the outputs of a run (DESIGN §4 "On-disk outputs of a run").

A run folder holds: odometry.tum (published IMU poses in the odometry frame), causal.tum (each pose
as published in the map frame, with the map correction in effect then), final.tum (every pose
re-exported with the completed corrections), poses.csv (per pose: correction version and
interpolation fraction), report.json
(metrics, timings, counters, configuration, versions), config.toml (the resolved configuration)
and plots (trajectory and error against ground truth when the recording has it). When the filter
restarted after a divergence, odometry_segment<k>.tum, causal_segment<k>.tum and final_segment<k>.tum hold
each segment (its own odometry frame, and its own map frame: each segment starts a new submap graph),
report.json "segments" gives each one's ATE, and odometry.tum, causal.tum, final.tum and the metrics are
the last segment. Writes are atomic (temporary file + rename).
"""
from __future__ import annotations

import json
import platform
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from runtime.errors import DataError
from runtime.files import atomic_write_text
from runtime.geometry import PoseTrajectory
from runtime.json_out import strict_dumps


@dataclass
class OpenedRecording:
    """A driver plus what the run needs to know about where it came from.

    Attributes:
        driver: the EurocDriver reading the folder.
        kind: "euroc" | "simulated".
        description: one line for the console and the report.
        ground_truth_source: the rebuilt simulation's GroundTruthSource for the emulated DA3
            (simulated recordings opened with rebuild=True only; None otherwise).
        time_offset_s: a simulated folder's camera-IMU time offset from its manifest (t_imu = t_cam +
            offset; an ASL sensor.yaml has no field for it), or None.
    """

    driver: Any
    kind: str  # "euroc" | "simulated"
    description: str
    ground_truth_source: Any = None
    time_offset_s: float | None = None


def open_recording(path: str | Path, rebuild: bool = True, policy: str = "drop", rig: Any = None,
                   image_topic: str | None = None, imu_topic: str | None = None) -> OpenedRecording:
    """An EuRoC ASL folder, or a folder written by `davio simulate`.

    With `rebuild` a simulated folder's scene and motion are rebuilt from its manifest (preset or
    trajectory mode) for the emulated DA3 and checked against the folder's ground truth; without it
    (native-only runs need no ground-truth renderer) the folder is only read, and
    `ground_truth_source` is None. `policy` is the driver's intake policy ("drop" or "strict").

    A ROS bag (`drivers.rosbag.is_bag`) is read by the RosbagDriver with `rig` (or its CameraInfo) and the
    topics given or auto-detected.
    """
    from drivers.euroc import EurocDriver
    from drivers.rosbag import RosbagDriver, is_bag

    p = Path(path)
    if not p.exists():
        raise DataError("recording folder not found", p)
    if is_bag(p):
        bag = RosbagDriver(p, rig=rig, image_topic=image_topic, imu_topic=imu_topic, policy=policy)
        return OpenedRecording(bag, "bag", f"ROS bag {p} (images {bag.image_topic}, IMU {bag.imu_topic})")
    if image_topic or imu_topic:
        from runtime.errors import ConfigError

        raise ConfigError(f"{p} is not a ROS bag: --image-topic and --imu-topic apply to bags only")
    manifest = p / "manifest.json"
    driver = EurocDriver(p, policy=policy)
    if not manifest.exists():
        return OpenedRecording(driver, "euroc", f"EuRoC folder {p}")
    info = read_manifest(manifest)
    description = f"simulated recording {p} ({_describe_simulation(info)})"
    cfg = info.get("config")
    offset = cfg.get("time_offset_s") if isinstance(cfg, dict) else None   # checked; 0.0 is a known 0
    if not rebuild:
        return OpenedRecording(driver, "simulated", description, time_offset_s=offset)
    gt_file = driver.groundtruth()
    rec = _rebuild_simulation(info, manifest, gt_file)
    gt_sim = rec.groundtruth()
    if gt_file is not None and len(gt_file) and len(gt_sim):
        for t, p_file in ((gt_file.t_ns[0], gt_file.p[0]), (gt_file.t_ns[-1], gt_file.p[-1])):
            k = int(np.searchsorted(gt_sim.t_ns, t))
            if k >= len(gt_sim) or gt_sim.t_ns[k] != t or np.linalg.norm(gt_sim.p[k] - p_file) > 1e-3:
                raise DataError("the simulation rebuilt from manifest.json does not match the folder's "
                                "ground truth (edited folder, changed input files or another davio "
                                "version); `davio run --native-only` still works", manifest)
    return OpenedRecording(driver, "simulated", description, rec.gt_source, offset)


_TRAJECTORY_MODES = ("trajectory-spline", "euroc-trajectory")
MANIFEST_MAX_BYTES = 1 << 20
_MANIFEST_RANGES = {"seconds": (0.0, 4 * 3600.0), "imu_rate_hz": (10.0, 10_000.0),
                    "camera_rate_hz": (0.2, 1000.0), "time_offset_s": (-1.0, 1.0), "start_s": (0.0, 1e6),
                    "attitude_smoothing_s": (0.01, 60.0)}
"""Plausible values of a `davio simulate` manifest's config (a simulation longer than 4 h would take
days to rebuild)."""


def read_manifest(manifest: Path) -> dict:
    """A `davio simulate` manifest.json, checked: size, UTF-8, JSON object, plausible config values."""
    import math

    try:
        size = manifest.stat().st_size
        if size > MANIFEST_MAX_BYTES:
            raise DataError(f"{size} bytes is too large for a simulation manifest (limit "
                            f"{MANIFEST_MAX_BYTES} bytes)", manifest)
        info = json.loads(manifest.read_bytes().decode("utf-8"))
    except OSError as exc:
        raise DataError(f"cannot read manifest: {exc.strerror or exc}", manifest) from exc
    except UnicodeDecodeError as exc:
        raise DataError(f"manifest.json is not UTF-8 text (byte {exc.start})", manifest) from exc
    except json.JSONDecodeError as exc:
        raise DataError(f"manifest.json is not valid JSON: {exc}", manifest) from exc
    if not isinstance(info, dict):
        raise DataError("manifest.json must hold a JSON object", manifest)
    cfg = info.get("config")
    for key, (lo, hi) in _MANIFEST_RANGES.items():
        v = cfg.get(key) if isinstance(cfg, dict) else None
        if v is None:
            continue
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or not lo <= v <= hi:
            raise DataError(f"config.{key} = {v!r} is implausible (expected {lo:g} to {hi:g}); the manifest "
                            "is damaged or was not written by `davio simulate`", manifest)
    seed = cfg.get("seed") if isinstance(cfg, dict) else None
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**32):
        raise DataError(f"config.seed = {seed!r} is not an integer from 0 to {2**32 - 1}; the manifest is "
                        "damaged or was not written by `davio simulate`", manifest)
    if "simulation" in info and not isinstance(info["simulation"], dict):
        raise DataError(f"'simulation' is {info['simulation']!r}, expected an object; the manifest is "
                        "damaged or was not written by `davio simulate`", manifest)
    mode = cfg.get("groundtruth_mode") if isinstance(cfg, dict) else None
    if mode is not None and mode not in ("imu-consistent", "as-recorded"):
        raise DataError(f"config.groundtruth_mode = {mode!r} is not 'imu-consistent' or 'as-recorded'; the "
                        "manifest is damaged or was written by a newer `davio simulate`", manifest)
    span = cfg.get("scene_span") if isinstance(cfg, dict) else None
    if span is not None and span not in ("recording", "trajectory"):
        raise DataError(f"config.scene_span = {span!r} is not 'recording' or 'trajectory'; the manifest is "
                        "damaged or was written by a newer `davio simulate`", manifest)
    return info


def _describe_simulation(info: dict) -> str:
    """The manifest's `simulation` entry in one line, numbers rounded."""
    sim = info.get("simulation")
    if not isinstance(sim, dict):
        return str(sim)
    return ", ".join(f"{k} {round(v, 3) if isinstance(v, float) else v}" for k, v in sim.items())


def _rebuild_simulation(info: dict, manifest: Path, groundtruth: PoseTrajectory | None = None) -> Any:
    """The SimRecording that `manifest` (a `davio simulate` manifest.json, parsed as `info`)
    describes, rebuilt with the default rig at the recorded time offset.

    Preset mode needs only the manifest. Trajectory modes ("trajectory-spline", "euroc-trajectory")
    re-read the trajectory file or euroc_imu_gt folder the manifest names (DataError naming it when
    it is gone); the replayed IMU file, when gone, is replaced by the folder's own imu0 (the same
    rows). `groundtruth` (the folder's) gives the crop start for manifests that predate `start_s`.
    """
    from dataclasses import replace

    from drivers.sim import SimConfig, SimRecording
    from drivers.sim.imu_consistent import DEFAULT_SMOOTHING_S

    try:
        cfg = info["config"]
        sim = info["simulation"]
        mode = sim.get("mode", "preset")
        base = SimConfig(preset=cfg["preset"], seconds=cfg["seconds"], seed=cfg["seed"], style=cfg["style"],
                         imu_rate_hz=cfg["imu_rate_hz"], time_offset_s=cfg.get("time_offset_s") or 0.0,
                         camera_rate_hz=cfg.get("camera_rate_hz"), start_s=cfg.get("start_s") or 0.0,
                         # recordings from before the key were rendered from the ground truth's attitude
                         groundtruth_mode=cfg.get("groundtruth_mode", "as-recorded"),
                         attitude_smoothing_s=cfg.get("attitude_smoothing_s", DEFAULT_SMOOTHING_S),
                         scene_span=cfg.get("scene_span", "recording"))
    except (KeyError, TypeError, AttributeError) as exc:
        raise DataError(f"manifest.json lacks {exc}", manifest) from exc
    if mode == "preset":
        return SimRecording.from_preset(base)
    if mode not in _TRAJECTORY_MODES:
        raise DataError(f"the emulated DA3 cannot rebuild a simulation of mode {mode!r}; "
                        "`davio run --native-only` still works", manifest)
    inputs = info.get("inputs") or {}
    source = _input_file(inputs.get("source"), sim.get("source"), "trajectory file", manifest)
    folder_mode = source.is_dir()
    gt_path = source
    if folder_mode:
        gt_path = next((source / n for n in ("groundtruth.csv", "groundtruth_tum.txt")
                        if (source / n).is_file()), source / "groundtruth.csv")
        _require_file(gt_path, "ground-truth file", manifest)
    imu = None
    if mode == "euroc-trajectory" and not folder_mode:
        named = inputs.get("imu") or sim.get("imu")
        imu = next((Path(c) for c in (inputs.get("imu"), sim.get("imu")) if c and Path(c).is_file()), None)
        if imu is None:  # the folder's imu0 holds the replayed rows
            imu = manifest.parent / "mav0" / "imu0" / "data.csv"
            _require_file(imu, f"IMU file (named {named!r} in the manifest, also gone)", manifest)
    elif folder_mode:
        _require_file(source / "imu0.csv", "IMU file", manifest)
    if "start_s" not in cfg and groundtruth is not None and len(groundtruth):
        from drivers.trajectory_files import read_trajectory

        first = int(read_trajectory(gt_path).t_ns[0])
        base = replace(base, start_s=(int(groundtruth.t_ns[0]) - first) * 1e-9)
    if folder_mode:
        return SimRecording.from_euroc_imu_gt(source, base)
    return SimRecording.from_trajectory(source, base, imu_path=imu)


def _input_file(resolved: str | None, recorded: str | None, what: str, manifest: Path) -> Path:
    """The first existing of the manifest's absolute and as-recorded paths of an input file."""
    for c in (resolved, recorded):
        if c and Path(c).exists():
            return Path(c)
    if not (resolved or recorded):
        raise DataError(f"manifest.json names no {what} to rebuild the simulation from; "
                        "`davio run --native-only` still works (it needs no rebuild)", manifest)
    return _require_file(Path(resolved or recorded), what, manifest)


def _require_file(path: Path, what: str, manifest: Path) -> Path:
    if not path.exists():
        raise DataError(f"cannot rebuild the simulation for the emulated DA3: its {what} {path} is "
                        "missing (restore it, or run with --native-only, which needs no rebuild)", manifest)
    return path


def published_segments(published: list) -> list[list]:
    """The published states split where the filter restarted after a divergence (each segment has its
    own odometry frame; `Published.segment` numbers them)."""
    out: list[list] = []
    for p in published:
        if not out or out[-1][-1].segment != p.segment:
            out.append([])
        out[-1].append(p)
    return out


def segment_bounds(segment: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of each run of equal values in `segment` (the filter's restarts), in order."""
    segment = np.asarray(segment)
    if not len(segment):
        return []
    cuts = [0, *(np.flatnonzero(np.diff(segment) != 0) + 1).tolist(), len(segment)]
    return list(zip(cuts[:-1], cuts[1:], strict=True))


def rows_trajectory(rows: np.ndarray) -> PoseTrajectory:
    """Published states as rows of `runtime.pose_history.ROW` -> their IMU poses (odometry frame)."""
    return PoseTrajectory(rows["t_ns"], rows["p_OI"], rows["R_OI"], v=rows["v_OI"])


def published_trajectory(published: list) -> PoseTrajectory:
    """The published IMU poses (odometry frame) as a trajectory (one pose per frame)."""
    if not published:
        return PoseTrajectory(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3, 3)))
    return PoseTrajectory([p.t_ns for p in published], [p.p_OI for p in published],
                          [p.R_OI for p in published], v=[p.v_OI for p in published])


def versions() -> dict:
    """Versions of DAVIO and the packages that shape its numbers."""
    from importlib.metadata import PackageNotFoundError, version

    out = {"python": platform.python_version(), "machine": platform.machine()}
    for name in ("davio", "numpy", "scipy", "numba", "opencv-python-headless", "onnxruntime"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            pass
    return out


def evaluate(est: PoseTrajectory, gt: PoseTrajectory | None) -> dict:
    """ATE (se3 and posyaw) of the published trajectory against ground truth, when both exist."""
    from tools.evaluation import ate

    if gt is None or len(est) < 3:
        return {}
    out = {}
    for method in ("se3", "posyaw"):
        try:
            r = ate(est, gt, align_method=method)
            out[f"ate_{method}_m"] = r.trans["rmse"]
            out["pairs"] = int(len(r.t_ns))
        except DataError as exc:
            out[f"ate_{method}_error"] = str(exc)
    return out


def imu_noise_note(defaulted: list[str]) -> str | None:
    """The console note for IMU noise densities the calibration withheld (`MsckfConfig.defaulted_imu_noise`),
    or None when it gave them all."""
    if not defaulted:
        return None
    return (f"note: IMU noise withheld in the calibration: {', '.join(defaulted)} from the EuRoC (ADIS16448) "
            "defaults; give an IMU calibration (imu.yaml beside the camchain, imu0/sensor.yaml) or set them "
            "in [msckf]")


def rig_summary(rig: Any, source: str) -> dict:
    """The calibration a run used, for report.json: where it came from, the camera, T_IC and the time
    offset (None where withheld)."""
    cam = rig.camera
    return {"source": source, "name": rig.name,
            "camera": None if cam is None else {"model": repr(cam), "width": cam.width, "height": cam.height,
                                                "K": cam.K.tolist()},
            "T_IC": None if rig.T_IC is None else np.asarray(rig.T_IC).tolist(),
            "time_offset_s": rig.time_offset_s,
            "imu_noise": None if rig.imu is None else {f: getattr(rig.imu, f) for f in (
                "gyro_noise_density", "gyro_random_walk", "accel_noise_density", "accel_random_walk")}}


RUN_OUTPUTS = re.compile(r"^((odometry|causal|final)(_segment\d+)?\.tum|groundtruth\.tum|poses\.csv|"
                         r"causal\.prior\.tum|final\.prior\.tum|causal\.earlier-prior\.tum|alignment\.json|"
                         r"events\.jsonl|"
                         r"config\.toml|report\.json|trajectory\.png|position_error\.png)$")
"""Names of the files `write_run` (and `davio demo`'s groundtruth.tum, the run's events.jsonl) put in a run
folder."""


def write_run(out_dir: Path, pipeline: Any, sched_report: Any, gt: PoseTrajectory | None,
              extra: dict, config: Any) -> dict:
    """Write odometry.tum, config.toml, report.json and plots; returns the report."""
    from runtime.config_io import config_to_dict, dump_toml
    from tools.evaluation import write_tum

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = pipeline.history.rows()       # every published state, as columns (no per-pose objects)
    bounds = segment_bounds(rows["segment"])
    final_T = np.asarray(pipeline.final_poses()).reshape(-1, 4, 4) if bounds else np.zeros((0, 4, 4))
    segments = [{"poses": b - a, "start_t_ns": int(rows["t_ns"][a]),
                 "source": pipeline.history.source(rows["source"][a])} for a, b in bounds]
    in_map = [(int(rows["segment"][a]), *map_frame_trajectories(rows[a:b], final_T[a:b])) for a, b in bounds]
    if len(bounds) > 1:  # restarts after a divergence: every segment has its own odometry and map frame
        for k, (a, b) in enumerate(bounds):
            seg_est = rows_trajectory(rows[a:b])
            write_tum(out_dir / f"odometry_segment{k}.tum", seg_est)
            write_tum(out_dir / f"causal_segment{k}.tum", in_map[k][1])
            write_tum(out_dir / f"final_segment{k}.tum", in_map[k][2])
            segments[k]["metrics"] = evaluate(seg_est, gt)
    start = bounds[-1][0] if bounds else 0
    est = rows_trajectory(rows[start:])
    write_tum(out_dir / "odometry.tum", est)  # atomic
    causal, final = map_frame_trajectories(rows[start:], final_T[start:])
    write_tum(out_dir / "causal.tum", causal)
    write_tum(out_dir / "final.tum", final)
    from tools.run_prior_frame import write_prior_frame

    prior = write_prior_frame(out_dir, pipeline, in_map, sched_report.first_t_ns)
    _write_pose_table(out_dir / "poses.csv", pipeline)
    atomic_write_text(out_dir / "config.toml", dump_toml(config))
    st = pipeline.startup.report if pipeline.startup is not None else None
    t0 = sched_report.first_t_ns
    t_pub = None if st is None else st.first_publish_t_ns
    report = {
        "schema": 1,
        **extra,
        "published_poses": len(rows),
        "segments": segments,
        "metrics_segment": len(bounds) - 1 if bounds else None,
        "published_by": None if st is None else st.published_by,
        "first_published_by": None if st is None else st.first_published_by,
        "T_f_s": None if t_pub is None or t0 is None else (t_pub - t0) * 1e-9,
        "metrics": evaluate(est, gt),
        "metrics_causal": evaluate(causal, gt),
        "metrics_final": evaluate(final, gt),
        "scheduler": sched_report.as_dict(),
        "prior_map": prior,
        "pipeline": pipeline.report(),
        "config": config_to_dict(config),
        "versions": versions(),
    }
    atomic_write_text(out_dir / "report.json", strict_dumps(report, indent=2))
    if gt is not None and len(est) >= 3:
        _plots(out_dir, est, gt)
    return report


def map_frame_trajectories(rows: np.ndarray, final_T: np.ndarray) -> tuple[PoseTrajectory, PoseTrajectory]:
    """(causal, final) IMU trajectories in the map frame of published states of one segment (`rows` of
    `runtime.pose_history.ROW`, `final_T` (N,4,4) their `final_poses`): causal = each pose as published,
    T_MO(t) T_OI(t) with the correction in effect then; final = every pose re-exported with the completed
    corrections."""
    return (PoseTrajectory(rows["t_ns"], rows["T_MI"][:, :, 3], rows["T_MI"][:, :, :3]),
            PoseTrajectory(rows["t_ns"], final_T[:, :3, 3], final_T[:, :3, :3]))


def _write_pose_table(path: Path, pipeline: Any) -> None:
    """poses.csv: every published state with its segment, source, and the map correction version and
    interpolation fraction it was published with."""
    h = pipeline.history
    r = h.rows()
    names = [h.source(c) for c in range(int(r["source"].max()) + 1)] if len(r) else []
    lines = ["t_ns,t_cam_ns,segment,source,correction_version,interpolation_fraction"]
    lines += [f"{t},{tc},{seg},{names[src]},{version},{fraction:.6f}" for t, tc, seg, src, version, fraction
              in zip(r["t_ns"].tolist(), r["t_cam_ns"].tolist(), r["segment"].tolist(), r["source"].tolist(),
                     r["version"].tolist(), r["fraction"].tolist(), strict=True)]
    atomic_write_text(path, "\n".join(lines) + "\n")


def _plots(out_dir: Path, est: PoseTrajectory, gt: PoseTrajectory) -> None:
    from tools.evaluation import align, associate
    from tools.evaluation.plots import plot_errors, plot_trajectories

    try:
        e, r = associate(est, gt)
        aligned, _ = align(e, r, "posyaw")
    except DataError:
        return
    plot_trajectories(out_dir / "trajectory.png", r, aligned, "published odometry (posyaw-aligned)")
    err = np.linalg.norm(aligned.p - r.p, axis=1)
    plot_errors(out_dir / "position_error.png", r.t_ns, err, "m", "position error after posyaw alignment")
