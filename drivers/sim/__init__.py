"""Simulated camera-IMU recordings with exact ground truth (scenes, renderer, splines, IMU, writer).

Main entry points:
  SimRecording.from_preset(SimConfig(preset=..., seconds=..., seed=...))   in-memory driver
  SimRecording.from_euroc_imu_gt(folder) / from_trajectory(path, imu_path=...)  EuRoC-trajectory mode
  write_euroc(recording, out_dir)                                           EuRoC ASL folder
  GroundTruthSource / GroundTruthView                                      ground truth for the emulated DA3
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from runtime.lazy_exports import lazy_exports

# name -> module: imported on first use (PEP 562), so that `drivers.sim.motion` and the others do not pull
# in the renderer and the pipeline (the `davio` command reads the presets when it builds its options)
_EXPORTS = {
    "GroundTruthSource": "drivers.sim.groundtruth", "GroundTruthView": "drivers.sim.groundtruth",
    "ImuErrorModel": "drivers.sim.imu_synth", "ImuStream": "drivers.sim.imu_synth",
    "synthesize_imu": "drivers.sim.imu_synth",
    "DEFAULT_PRESET": "drivers.sim.motion", "PRESETS": "drivers.sim.motion",
    "preset_spline": "drivers.sim.motion",
    "SimConfig": "drivers.sim.recording", "SimRecording": "drivers.sim.recording",
    "ImageOptions": "drivers.sim.render", "Renderer": "drivers.sim.render",
    "Scene": "drivers.sim.scene", "build_scene": "drivers.sim.scene",
    "PoseSpline": "drivers.sim.spline", "fit_pose_spline": "drivers.sim.spline",
    "write_euroc": "drivers.sim.writer",
}

if TYPE_CHECKING:
    from drivers.sim.groundtruth import GroundTruthSource, GroundTruthView
    from drivers.sim.imu_synth import ImuErrorModel, ImuStream, synthesize_imu
    from drivers.sim.motion import DEFAULT_PRESET, PRESETS, preset_spline
    from drivers.sim.recording import SimConfig, SimRecording
    from drivers.sim.render import ImageOptions, Renderer
    from drivers.sim.scene import Scene, build_scene
    from drivers.sim.spline import PoseSpline, fit_pose_spline
    from drivers.sim.writer import write_euroc


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)


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
