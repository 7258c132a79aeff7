"""Mapping configuration (paper Sec. III and V): keyframe windows, the conditioned-call gates, frame
scales, multi-view rejection and voxel fusion. Defaults are the paper's numbers."""
from __future__ import annotations

from dataclasses import dataclass

from runtime.config_checks import at_least, each_at_least, in_range, non_negative, positive
from runtime.errors import ConfigError

MIN_VOXEL_M = 0.005
"""Smallest fusion voxel (m): the grid spans +-2^20 voxels (+-5 km at 5 mm; runtime.mapping.fusion)."""
MAX_VOXEL_M = 10.0
"""Largest fusion voxel (m)."""


@dataclass
class MappingConfig:
    """Pose-conditioned dense mapping."""

    enabled: bool = True
    """Map whenever a depth model is given (`davio run --no-map` turns it off)."""
    graph: bool = True
    """Place submaps with the submap graph (off: the filter's poses as they are, lambda = 0)."""
    archive_views: bool = True
    """Store each submap's centre view in the map archive (about 0.23 MB of a submap's 0.9 MB), so that a
    later run can be localised in the map (`--prior-map`, `davio map align`); false saves that disk."""
    keyframe_spacing_s: float = 0.5
    """Keyframes at this sensor-time spacing during tracking (Sec. III)."""
    window_images: int = 5
    """Keyframes per mapping window."""
    shared_images: int = 2
    """Keyframes shared by consecutive windows (a new window every window_images - shared_images)."""
    max_pending_windows: int = 2
    """Bounded mapping queue: when it is full the oldest pending window is dropped (counted)."""
    min_baseline_m: float = 0.05
    """Accept a window only if its metric baseline (largest camera-centre distance) exceeds this."""
    max_fit_rmse_m: float = 0.15
    """... and the similarity fit of returned to VIO camera centres has at most this RMSE ..."""
    max_abs_log_scale: float = 0.3
    """... and |log s_hat| of that fit is at most this."""
    frame_scale_rounds: int = 8
    """Rounds of depth-normalised, outlier-reweighted least squares for the per-frame scales."""
    frame_scale_prior_sigma: float = 0.1
    """Weak unit prior on each per-frame scale (in units of the depth-normalised residual)."""
    frame_scale_huber: float = 0.05
    """Scale of the outlier weights 1 / (1 + (r / this)^2) on the depth-normalised match residual."""
    frame_scale_min_matches: int = 20
    """Pairs with fewer matches than this do not enter the per-frame scale solve."""
    frame_scale_pair_offsets: tuple[int, ...] = (1, 2)
    """Images this many positions apart are matched for the per-frame scales."""
    multiview_rel_depth: float = 0.10
    """A depth is kept only if another frame of the window re-observes it within this relative depth..."""
    multiview_keep_unseen: bool = True
    """... or if no other frame of the window sees it at all (outside their images or on pixels without a
    valid depth), so it can be neither confirmed nor contradicted (counted as `points_unverified`).
    Not in the paper: its rule (false here) drops every surface only one image of a window sees, which
    cost 1.3-7.2 points of recall, for precision within 0.007, in `davio bench mapping` (BENCHMARKS.md)."""
    max_multiview_failed_fraction: float = 0.5
    """A window is refused as a whole (reason "multiview") when more than this fraction of its depths that
    another image sees fail the multi-view test: the model's depths then disagree between the images of one
    window far beyond the published DA3 errors, and a submap built from them would pull the submap graph
    (every adjacent point group is kept) and spoil the map. Not in the paper; 1.0 turns it off. Measured on
    the MH_03 simulation (BENCHMARKS.md "Trajectory"): at most 12 % per window with the emulated DA3-Base,
    at least 63 % with its depth errors x20."""
    conf_percentile: float = 25.0
    """DA3 confidence filter: pixels below this percentile of the window's confidence are dropped."""
    pixel_stride: int = 4
    """Depth pixels are sampled on this grid (pixels) before rejection, fusion and archiving."""
    max_depth_m: float = 20.0
    """Depths beyond this are not mapped (DA3's far range is unreliable)."""
    min_valid_depth_fraction: float = 0.25
    """A window is refused as a whole (reason "invalid_depth") when fewer than this fraction of its sampled
    depths are finite and in (0, max_depth_m]: a graph whose depth is in other units (mm), inverse or
    negative, or a scene mostly beyond the range, maps nothing (it committed empty submaps). Not in the
    paper."""
    voxel_m: float = 0.04
    """Fusion voxel size (m)."""
    max_resident_submaps: int = 24
    """Submaps kept in memory (their voxels stay fused; older ones leave memory, archives stay on disk)."""
    min_overlap_pixels: int = 200
    """Fewest aligned valid pixels for a shared-image or projected-overlap depth ratio."""
    min_scale_sigma: float = 0.03
    """Floor of sigma_ab for the shared-image scale residual (eq. shared)."""
    graph_points: int = 80
    """Most correspondences of a point group between the centre images of two submaps."""
    graph_min_points: int = 10
    """Fewer verified correspondences than this add no point group."""
    refuse_tolerance_m: float = 0.005
    """A resident submap the graph moved by less than this (m, at its farthest point) is not re-fused into
    the live grid (a fraction of a voxel; its archived state and the final export are exact)."""

    def __post_init__(self) -> None:
        s = "mapping"
        positive(self, s, "keyframe_spacing_s", "max_fit_rmse_m", "max_abs_log_scale",
                 "frame_scale_prior_sigma", "frame_scale_huber", "multiview_rel_depth", "max_depth_m",
                 "min_scale_sigma")
        non_negative(self, s, "min_baseline_m", "refuse_tolerance_m")
        in_range(self, s, "voxel_m", MIN_VOXEL_M, MAX_VOXEL_M)
        in_range(self, s, "max_multiview_failed_fraction", 0.0, 1.0)
        in_range(self, s, "min_valid_depth_fraction", 0.0, 1.0)
        in_range(self, s, "conf_percentile", 0.0, 100.0, hi_open=True)
        at_least(self, s, 1, "max_pending_windows", "frame_scale_rounds", "frame_scale_min_matches",
                 "pixel_stride", "max_resident_submaps", "min_overlap_pixels", "graph_points",
                 "graph_min_points")
        at_least(self, s, 2, "window_images")
        at_least(self, s, 0, "shared_images")
        if self.shared_images >= self.window_images:
            raise ConfigError(f"mapping.shared_images must be below mapping.window_images "
                              f"({self.window_images}), got {self.shared_images}")
        each_at_least(self.frame_scale_pair_offsets, s, "frame_scale_pair_offsets", 1)
