"""Simulated camera-IMU recordings with exact ground truth (scenes, renderer, splines, IMU, writer).

Main entry points:
  SimRecording.from_preset(SimConfig(preset=..., seconds=..., seed=...))   in-memory driver
  SimRecording.from_euroc_imu_gt(folder) / from_trajectory(path, imu_path=...)  EuRoC-trajectory mode
  write_euroc(recording, out_dir)                                           EuRoC ASL folder
  GroundTruthSource / GroundTruthView                                      ground truth for the emulated DA3
"""

from __future__ import annotations

from drivers.sim.groundtruth import GroundTruthSource, GroundTruthView
from drivers.sim.imu_synth import ImuErrorModel, ImuStream, synthesize_imu
from drivers.sim.motion import DEFAULT_PRESET, PRESETS, preset_spline
from drivers.sim.recording import SimConfig, SimRecording
from drivers.sim.render import ImageOptions, Renderer
from drivers.sim.scene import Scene, build_scene
from drivers.sim.spline import PoseSpline, fit_pose_spline
from drivers.sim.writer import write_euroc

__all__ = [
    "DEFAULT_PRESET",
    "PRESETS",
    "GroundTruthSource",
    "GroundTruthView",
    "ImageOptions",
    "ImuErrorModel",
    "ImuStream",
    "PoseSpline",
    "Renderer",
    "Scene",
    "SimConfig",
    "SimRecording",
    "build_scene",
    "fit_pose_spline",
    "preset_spline",
    "synthesize_imu",
    "write_euroc",
]
