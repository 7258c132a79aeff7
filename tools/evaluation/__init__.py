"""Trajectory and map evaluation: TUM/EuRoC I/O, association, alignment, ATE/RPE, surface metrics.

Definitions follow evo (`evo_ape`, `evo_rpe`) so that numbers agree on the same files; the
position+yaw (4-DoF) alignment, absent from evo, follows the VIO convention (OpenVINS ov_eval).
"""
from __future__ import annotations

from tools.evaluation.align import METHODS, Alignment, align, posyaw, umeyama
from tools.evaluation.associate import associate, match_stamps
from tools.evaluation.degenerate import ate_degenerate_truth, truth_is_degenerate
from tools.evaluation.metrics import AteResult, RpeResult, ate, error_stats, rpe
from tools.evaluation.surface import SurfaceResult, read_point_cloud, surface_metrics, voxel_downsample
from tools.evaluation.trajectory_io import (
    detect_format,
    read_euroc_csv,
    read_trajectory,
    read_tum,
    write_euroc_csv,
    write_tum,
)

__all__ = ["METHODS", "Alignment", "AteResult", "RpeResult", "SurfaceResult", "align", "associate", "ate",
           "ate_degenerate_truth", "truth_is_degenerate",
           "detect_format", "error_stats", "match_stamps", "posyaw", "read_euroc_csv", "read_point_cloud",
           "read_trajectory", "read_tum", "rpe", "surface_metrics", "umeyama", "voxel_downsample",
           "write_euroc_csv", "write_tum"]
