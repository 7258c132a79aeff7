"""Opening recordings and writing the outputs of a run (DESIGN §4 "On-disk outputs of a run").

A run folder holds: odometry.tum (published IMU poses in the odometry frame), report.json
(metrics, timings, counters, configuration, versions), config.toml (the resolved configuration)
and plots (trajectory and error against ground truth when the recording has it). When the filter
restarted after a divergence, odometry_segment<k>.tum holds each segment (its own odometry frame) and
odometry.tum and the metrics are the last segment. Writes are atomic (temporary file + rename).
"""
from __future__ import annotations

import json
import platform
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from runtime.errors import DataError
from runtime.geometry import PoseTrajectory
from tools.evaluation.trajectory_io import atomic_write_text


@dataclass
class OpenedRecording:
    """A driver plus what the run needs to know about where it came from."""

    driver: Any
    kind: str  # "euroc" | "simulated"
    description: str
    ground_truth_source: Any = None  # for the emulated DA3 (simulated recordings only)


def open_recording(path: str | Path) -> OpenedRecording:
    """An EuRoC ASL folder, or a folder written by `davio simulate` (its scene is rebuilt from the
    manifest for the emulated DA3 and checked against the folder's ground truth)."""
    from drivers.euroc import EurocDriver

    p = Path(path)
    if not p.exists():
        raise DataError("recording folder not found", p)
    manifest = p / "manifest.json"
    driver = EurocDriver(p)
    if not manifest.exists():
        return OpenedRecording(driver, "euroc", f"EuRoC folder {p}")
    try:
        info = json.loads(manifest.read_text())
    except json.JSONDecodeError as exc:
        raise DataError(f"manifest.json is not valid JSON: {exc}", manifest) from exc
    rec = _rebuild_simulation(info, manifest)
    gt_file, gt_sim = driver.groundtruth(), rec.groundtruth()
    if gt_file is not None and len(gt_file) and len(gt_sim):
        k = int(np.searchsorted(gt_sim.t_ns, gt_file.t_ns[0]))
        if k >= len(gt_sim) or np.linalg.norm(gt_sim.p[k] - gt_file.p[0]) > 1e-3:
            raise DataError("the simulation rebuilt from manifest.json does not match the folder's "
                            "ground truth (edited folder or another davio version)", manifest)
    return OpenedRecording(driver, "simulated", f"simulated recording {p} ({info['simulation']})",
                           rec.gt_source)


def _rebuild_simulation(info: dict, manifest: Path) -> Any:
    from drivers.sim import SimConfig, SimRecording

    try:
        cfg = info["config"]
        sim = info["simulation"]
        mode = sim.get("mode", "preset")
        base = SimConfig(preset=cfg["preset"], seconds=cfg["seconds"], seed=cfg["seed"], style=cfg["style"],
                         imu_rate_hz=cfg["imu_rate_hz"], time_offset_s=cfg.get("time_offset_s") or 0.0)
    except (KeyError, TypeError) as exc:
        raise DataError(f"manifest.json lacks {exc}", manifest) from exc
    if mode == "preset":
        return SimRecording.from_preset(base)
    raise DataError(f"the emulated DA3 can only rebuild preset simulations, not mode {mode!r}; "
                    "run it in memory with `davio bench startup` instead", manifest)


def published_segments(published: list) -> list[list]:
    """The published states split where the filter restarted after a divergence (each segment has its
    own odometry frame; `Published.segment` numbers them)."""
    out: list[list] = []
    for p in published:
        if not out or out[-1][-1].segment != p.segment:
            out.append([])
        out[-1].append(p)
    return out


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


def write_run(out_dir: Path, pipeline: Any, sched_report: Any, gt: PoseTrajectory | None,
              extra: dict, config: Any) -> dict:
    """Write odometry.tum, config.toml, report.json and plots; returns the report."""
    from runtime.config_io import config_to_dict, dump_toml
    from tools.evaluation import write_tum

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    segments = published_segments(pipeline.published)
    if len(segments) > 1:  # restarts after a divergence: every segment has its own odometry frame
        for k, seg in enumerate(segments):
            write_tum(out_dir / f"odometry_segment{k}.tum", published_trajectory(seg))
    est = published_trajectory(segments[-1] if segments else [])
    write_tum(out_dir / "odometry.tum", est)  # atomic
    atomic_write_text(out_dir / "config.toml", dump_toml(config))
    st = pipeline.startup.report if pipeline.startup is not None else None
    t0 = sched_report.first_t_ns
    t_pub = None if st is None else st.first_publish_t_ns
    report = {
        "schema": 1,
        **extra,
        "published_poses": len(pipeline.published),
        "segments": [{"poses": len(seg), "start_t_ns": seg[0].t_ns, "source": seg[0].source}
                     for seg in segments],
        "metrics_segment": len(segments) - 1 if segments else None,
        "published_by": None if st is None else st.published_by,
        "T_f_s": None if t_pub is None or t0 is None else (t_pub - t0) * 1e-9,
        "metrics": evaluate(est, gt),
        "scheduler": sched_report.as_dict(),
        "pipeline": pipeline.report(),
        "config": config_to_dict(config),
        "versions": versions(),
    }
    atomic_write_text(out_dir / "report.json", json.dumps(report, indent=2, default=_json_default))
    if gt is not None and len(est) >= 3:
        _plots(out_dir, est, gt)
    return report


def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    return str(o)


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
