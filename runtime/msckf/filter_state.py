"""What the filter publishes and counts: the per-frame snapshot (FilterState) and the counters behind
MsckfEstimator.report()."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class FilterState:
    """A snapshot of the filter after one frame.

    t_ns: IMU-clock time of the state (ns); t_cam_ns: the camera time of the frame (ns);
    R_OI, p_OI, v_OI, bg, ba: IMU state in the gravity-aligned odometry frame O;
    covariance: (15, 15) IMU block, order [dtheta (body frame), dp, dv, dbg, dba];
    R_IC, p_IC, time_offset_s: current calibration (t_imu = t_cam + time_offset_s);
    calib_covariance: (7, 7) covariance of [dphi (right on R_IC), dp_IC, dt] for the estimated blocks
    (extrinsics 6 then time offset 1; None when neither is estimated);
    intrinsics: (12,) camera parameters in use [fx, fy, cx, cy, d0..d7] (px, px, px, px, unitless), the
    state's estimate with online intrinsics calibration; intrinsics_covariance: (8, 8) covariance of
    intrinsics[:8] when estimated (else None); intrinsics_std: the square roots of its diagonal.
    """

    t_ns: int
    t_cam_ns: int
    R_OI: np.ndarray
    p_OI: np.ndarray
    v_OI: np.ndarray
    bg: np.ndarray
    ba: np.ndarray
    covariance: np.ndarray
    R_IC: np.ndarray
    p_IC: np.ndarray
    time_offset_s: float
    calib_covariance: np.ndarray | None = None
    num_slam: int = 0
    num_clones: int = 0
    intrinsics: np.ndarray | None = None
    intrinsics_covariance: np.ndarray | None = None

    @property
    def intrinsics_std(self) -> np.ndarray | None:
        """(8,) prior/posterior std of the estimated intrinsics (None when they are not estimated)."""
        if self.intrinsics_covariance is None:
            return None
        return np.sqrt(np.maximum(np.diag(self.intrinsics_covariance), 0.0))


@dataclass
class FilterCounters:
    """Counts and times of one estimator (MsckfEstimator.report())."""

    imu_samples: int = 0
    imu_nonfinite: int = 0
    imu_out_of_order: int = 0
    imu_gaps: int = 0
    imu_lost: int = 0  #: samples a live driver reported lost before a sample (ImuSample.lost_before)
    frames: int = 0
    frames_processed: int = 0
    frames_out_of_order: int = 0
    frames_before_init: int = 0
    frames_no_imu: int = 0
    frames_bad_input: int = 0
    frames_without_features: int = 0
    msckf_features_used: int = 0
    msckf_triangulation_failed: int = 0
    msckf_chi2_rejected: int = 0
    #: stacked EKF updates (MSCKF, SLAM, landmark initialisation) not applied: innovation covariance not
    #: positive definite (a covariance that has lost definiteness)
    ekf_update_failed: int = 0
    slam_updates: int = 0
    slam_chi2_rejected: int = 0
    slam_initialized: int = 0
    slam_init_failed: int = 0
    slam_marginalized: int = 0
    slam_anchor_changes: int = 0
    zupt_applied: int = 0
    #: frames past the update step that accepted nothing while their tracks lacked the parallax to triangulate
    #: (MsckfConfig.visual_health_min_parallax_deg): not counted by the blind-filter check
    frames_low_parallax: int = 0
    initializations: int = 0
    divergence_resets: int = 0
    #: largest rejected share over a window of MsckfConfig.chi2_health_window_s seconds
    chi2_rejection_fraction_max: float = 0.0
    #: fewest visual measurements accepted over a full window of visual_health_window_s seconds
    visual_accepted_min: int | None = None
    init_sources: dict = field(default_factory=dict)
    divergence_reasons: list = field(default_factory=list)
    time_frame_s: float = 0.0
    cpu_frame_s: float = 0.0
