"""Write a simulated recording as a EuRoC ASL folder (+ depth maps, surface cloud, manifest).

Layout under DIR:
  mav0/cam0/data.csv, data/<t_ns>.png, sensor.yaml      (EuRoC format, %YAML:1.0 header)
  mav0/imu0/data.csv, sensor.yaml
  mav0/state_groundtruth_estimate0/data.csv              (p, q_wxyz, v, bg, ba of the IMU/body frame)
  mav0/depth0/data.csv, data/<t_ns>.png                  (z-depth of what cam0 sees, uint16 mm, 0 = none)
  scene_points.ply                                       (surface samples with albedo, binary PLY)
  manifest.json                                          (how it was made, rig, counts, versions)
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from runtime.errors import ConfigError
from runtime.geometry.quaternion import rot_to_quat_wxyz

if TYPE_CHECKING:
    from calib import Rig

DEPTH_SCALE_MM = 1000.0
"""Depth PNG units per metre (uint16 millimetres; 0 = no surface or beyond 65.535 m)."""

MANIFEST_SCHEMA = 1


def _yaml_matrix(T: np.ndarray) -> str:
    rows = [", ".join(f"{x:.12g}" for x in T[r]) for r in range(4)]
    return "T_BS:\n  cols: 4\n  rows: 4\n  data: [" + ",\n         ".join(rows) + "]\n"


def camera_sensor_yaml(rig: Rig) -> str:
    """EuRoC cam0/sensor.yaml text for the rig's camera (T_BS = T_IC)."""
    cam = rig.camera
    model = {"radtan": "radial-tangential", "equidistant": "equidistant", "none": "radial-tangential"}.get(
        cam.distortion_model
    )
    if model is None:
        raise ConfigError(f"cannot write a {cam.distortion_model} camera in EuRoC format")
    dist = list(cam.distortion) if cam.distortion.size else [0.0, 0.0, 0.0, 0.0]
    return (
        "%YAML:1.0\n# General sensor definitions.\nsensor_type: camera\ncomment: DAVIO simulator cam0\n\n"
        "# Sensor extrinsics wrt. the body-frame.\n"
        + _yaml_matrix(rig.T_IC)
        + f"\n# Camera specific definitions.\nrate_hz: {rig.camera_rate_hz or 20:g}\n"
        f"resolution: [{cam.width}, {cam.height}]\ncamera_model: pinhole\n"
        f"intrinsics: [{cam.fx:.12g}, {cam.fy:.12g}, {cam.cx:.12g}, {cam.cy:.12g}] #fu, fv, cu, cv\n"
        f"distortion_model: {model}\n"
        f"distortion_coefficients: [{', '.join(f'{d:.12g}' for d in dist)}]\n"
    )


def imu_sensor_yaml(rig: Rig, rate_hz: float) -> str:
    """EuRoC imu0/sensor.yaml text (identity T_BS: body = IMU frame)."""
    n = rig.imu

    def val(name: str, default: float) -> float:
        given = None if n is None else getattr(n, name)
        return given if given is not None else default

    return (
        "%YAML:1.0\n#Default imu sensor yaml file\nsensor_type: imu\ncomment: DAVIO simulator imu0\n\n"
        "# Sensor extrinsics wrt. the body-frame.\n" + _yaml_matrix(np.eye(4)) + f"rate_hz: {rate_hz:g}\n\n"
        "# inertial sensor noise model parameters (static)\n"
        f"gyroscope_noise_density: {val('gyro_noise_density', 1.6968e-04):.6g}     # [ rad / s / sqrt(Hz) ]\n"
        f"gyroscope_random_walk: {val('gyro_random_walk', 1.9393e-05):.6g}       # [ rad / s^2 / sqrt(Hz) ]\n"
        f"accelerometer_noise_density: {val('accel_noise_density', 2.0e-3):.6g}  # [ m / s^2 / sqrt(Hz) ]\n"
        f"accelerometer_random_walk: {val('accel_random_walk', 3.0e-3):.6g}    # [ m / s^3 / sqrt(Hz) ]\n"
    )


def write_groundtruth_csv(path: Path, gt) -> list[str]:
    """EuRoC state CSV of a PoseTrajectory; returns notes on fields that had to be derived."""
    from drivers.sim.sampled_motion import finite_difference_velocity

    notes = []
    v = gt.v
    if v is None:
        v = finite_difference_velocity(gt.t_ns, gt.p)
        notes.append("ground-truth velocity derived from positions by central differences")
    zeros = np.zeros((len(gt), 3))
    bg = gt.bg if gt.bg is not None else zeros
    ba = gt.ba if gt.ba is not None else zeros
    if gt.bg is None or gt.ba is None:
        notes.append("ground-truth biases unknown (real IMU): written as zeros")
    q = rot_to_quat_wxyz(gt.R)
    q = q * np.where(q[:, :1] < 0, -1.0, 1.0)
    header = (
        "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], "
        "v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], b_w_RS_S_x [rad s^-1], "
        "b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], "
        "b_a_RS_S_z [m s^-2]"
    )
    vals = np.concatenate([gt.p, q, v, bg, ba], axis=1)
    with path.open("w") as fh:
        fh.write(header + "\n")
        for t, row in zip(gt.t_ns, vals, strict=True):
            fh.write(f"{int(t)}," + ",".join(f"{x:.9g}" for x in row) + "\n")
    return notes


def write_ply(path: Path, points: np.ndarray, grey: np.ndarray) -> None:
    """Binary little-endian PLY with float32 x, y, z and uchar red/green/blue (= grey)."""
    n = points.shape[0]
    rec = np.zeros(
        n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")]
    )
    rec["x"], rec["y"], rec["z"] = points[:, 0], points[:, 1], points[:, 2]
    g = np.clip(np.rint(grey * 255), 0, 255).astype(np.uint8)
    rec["red"] = rec["green"] = rec["blue"] = g
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment DAVIO simulator scene surface samples\n"
        f"element vertex {n}\nproperty float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    )
    with path.open("wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(rec.tobytes())


def _versions() -> dict:
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for name in ("davio", "numpy", "numba", "opencv-python-headless"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            continue
    return out


def _input_files(info: dict) -> dict:
    """Absolute paths of the files a trajectory-mode simulation read (its trajectory file or
    euroc_imu_gt folder, and the replayed IMU), so that `davio run` can rebuild it from any folder."""
    if info.get("mode", "preset") == "preset":
        return {}
    return {key: str(Path(info[key]).resolve()) for key in ("source", "imu") if info.get(key)}


def write_euroc(
    recording,
    out_dir: str | Path,
    depth: bool = True,
    cloud_spacing_m: float | None = 0.05,
    progress: Callable[[int, int], None] | None = None,
) -> dict:
    """Render every frame of `recording` (a SimRecording) into out_dir in EuRoC ASL layout.

    Returns the manifest (also written to out_dir/manifest.json). `progress(done, total)` is
    called after each frame.
    """
    out = Path(out_dir)
    mav = out / "mav0"
    if (mav / "cam0" / "data.csv").exists():
        raise ConfigError(f"{out} already holds a EuRoC recording; choose an empty --out folder")
    cam_dir, imu_dir = mav / "cam0", mav / "imu0"
    gt_dir, depth_dir = mav / "state_groundtruth_estimate0", mav / "depth0"
    for d in (cam_dir / "data", imu_dir, gt_dir) + ((depth_dir / "data",) if depth else ()):
        d.mkdir(parents=True, exist_ok=True)
    rig = recording.rig
    (cam_dir / "sensor.yaml").write_text(camera_sensor_yaml(rig))
    imu = recording.imu
    rate = 1e9 / float(np.median(np.diff(imu.t_ns)))
    (imu_dir / "sensor.yaml").write_text(imu_sensor_yaml(rig, round(rate, 3)))
    with (imu_dir / "data.csv").open("w") as fh:
        fh.write(
            "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
            "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n"
        )
        for t, w, a in zip(imu.t_ns, imu.gyro, imu.accel, strict=True):
            fh.write(f"{int(t)},{w[0]:.17g},{w[1]:.17g},{w[2]:.17g},{a[0]:.17g},{a[1]:.17g},{a[2]:.17g}\n")
    notes = write_groundtruth_csv(gt_dir / "data.csv", recording.groundtruth())
    notes = [*recording.info.get("notes", []), *notes]
    n = len(recording)
    cam_rows, depth_rows = [], []
    for k in range(n):
        frame, view = recording.render(k)
        name = f"{frame.t_ns}.png"
        if not cv2.imwrite(str(cam_dir / "data" / name), frame.image):
            raise ConfigError(f"could not write {cam_dir / 'data' / name}")
        cam_rows.append(f"{frame.t_ns},{name}")
        if depth:
            mm = np.where(np.isfinite(view.depth), np.rint(view.depth * DEPTH_SCALE_MM), 0)
            mm = np.where(mm > 65535, 0, mm).astype(np.uint16)
            cv2.imwrite(str(depth_dir / "data" / name), mm)
            depth_rows.append(f"{frame.t_ns},{name}")
        if progress is not None:
            progress(k + 1, n)
    (cam_dir / "data.csv").write_text("#timestamp [ns],filename\n" + "\n".join(cam_rows) + "\n")
    if depth:
        (depth_dir / "data.csv").write_text(
            "#timestamp [ns],filename (uint16 z-depth, mm, 0 = none)\n" + "\n".join(depth_rows) + "\n"
        )
    n_points = 0
    if cloud_spacing_m:
        pts, grey = recording.scene.surface_points(cloud_spacing_m)
        write_ply(out / "scene_points.ply", pts, grey)
        n_points = int(pts.shape[0])
    cam = rig.camera
    manifest = {
        "schema": MANIFEST_SCHEMA,
        "generator": "davio simulate",
        "simulation": {k: v for k, v in recording.info.items()},
        "config": {
            "preset": recording.config.preset,
            "seconds": recording.config.seconds,
            "seed": recording.config.seed,
            "style": recording.config.style,
            "imu_rate_hz": recording.config.imu_rate_hz,
            "time_offset_s": rig.time_offset_s,
            "image": recording.config.image.__dict__,
            "imu_errors": None
            if recording.config.imu_errors is None
            else recording.config.imu_errors.__dict__,
            "imu_profile": recording.config.imu_profile,
            "start_s": recording.config.start_s,
            "scene_span": recording.config.scene_span,
            "camera_rate_hz": recording.config.camera_rate_hz,
        },
        "inputs": _input_files(recording.info),
        "rig": {
            "name": rig.name,
            "camera_model": cam.distortion_model,
            "width": cam.width,
            "height": cam.height,
            "fx": cam.fx,
            "fy": cam.fy,
            "cx": cam.cx,
            "cy": cam.cy,
            "distortion": cam.distortion.tolist(),
            "T_IC": rig.T_IC.tolist(),
            "time_offset_s": rig.time_offset_s,
            "camera_rate_hz": rig.camera_rate_hz,
        },
        "scene": recording.scene.summary(),
        "counts": {
            "frames": n,
            "imu_samples": len(imu),
            "groundtruth_poses": len(recording.groundtruth()),
            "scene_points": n_points,
        },
        "gravity_mps2": 9.81,
        "depth": {"folder": "mav0/depth0", "units": "uint16 millimetres of z-depth, 0 = no surface"}
        if depth
        else None,
        "notes": notes,
        "versions": _versions(),
    }
    if recording.info.get("mode") == "euroc-trajectory":   # a real IMU replayed: what the images follow
        manifest["config"]["groundtruth_mode"] = recording.config.groundtruth_mode
        manifest["config"]["attitude_smoothing_s"] = recording.config.attitude_smoothing_s
    from runtime.json_out import strict_dumps

    (out / "manifest.json").write_text(strict_dumps(manifest, indent=2))
    return manifest
