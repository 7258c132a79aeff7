"""A submap: one accepted mapping window, its retained depths and its graph state (paper Sec. V)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from runtime.mapping.placement import place_points


@dataclass
class SubmapState:
    """The graph state of a committed submap that left memory (its points are in the archive only):
    what a commit reports when the graph moves it. Attributes as in `Submap`; n_points: archived points."""

    index: int
    frame_t_ns: np.ndarray
    centre: int
    T_OS: np.ndarray
    T_MS: np.ndarray
    lam: float
    version: int
    segment: int
    fit: dict
    n_points: int


@dataclass
class Submap:
    """The retained depths of one window, stored so that the graph can move and rescale it.

    Frames: S = the centre image's camera (submap frame S_j), C_i = camera of image i, O = the
    filter's odometry frame, M = the map frame.

    Attributes:
        index: submap number j (0, 1, ... in commit order).
        frame_t_ns: (N,) int64 camera stamps of the window's images.
        centre: index of the centre image (S_j = C_centre).
        T_OS: (4,4) T_OS_j, the filter's pose of S_j at the window (odometry frame, metric).
        T_SC: (N,4,4) L_ji = T_S_jC_i, the fixed metric VIO poses of the images relative to the centre.
        K: (3,3) rectified pinhole intrinsics the depths live in (pixels).
        s_hat: similarity-fit depth correction of the window (already applied to points_C).
        frame_scales: (N,) per-frame scales s_ji (unit geometric mean; already applied to points_C).
        points_C: (P,3) float32 retained points, each in its own image's camera frame, metres:
            s_hat s_ji d_ji(u) K^-1 u (the residual log-depth scale lambda is NOT applied).
        image: (P,) uint8 index of the image each point comes from.
        conf: (P,) float32 DA3 confidence (>= 1; comparable within the submap).
        grey: (P,) uint8 grey value of the rectified image at the pixel.
        T_MS: (4,4) graph state Q_j = T_MS_j (the identity graph: T_MO T_OS_j).
        lam: graph state lambda_j, residual log-depth scale.
        version: map version (commit number) that last changed this node's state.
        segment: the filter segment (restarts after a divergence start a new odometry frame).
        fit: the conditioned call's acceptance figures (baseline_m, fit_rmse_m, log_s_hat, ...).
        view: (Features, RevisitView) of the centre image as the revisits match it (the matcher's
            keypoints and descriptors, their corrected depths), or None without the graph; archived
            with the submap so that a later session can localise in the map (`davio map align`).
    """

    index: int
    frame_t_ns: np.ndarray
    centre: int
    T_OS: np.ndarray
    T_SC: np.ndarray
    K: np.ndarray
    s_hat: float
    frame_scales: np.ndarray
    points_C: np.ndarray
    image: np.ndarray
    conf: np.ndarray
    grey: np.ndarray
    T_MS: np.ndarray
    lam: float = 0.0
    version: int = 0
    segment: int = 0
    fit: dict = field(default_factory=dict)
    view: tuple | None = field(default=None, repr=False, compare=False)
    fused_state: tuple | None = field(default=None, repr=False, compare=False)
    """(T_MS, lambda) the live voxel grid holds this submap at (None: not in the grid)."""

    def __post_init__(self) -> None:
        n = len(self.frame_t_ns)
        p = len(self.points_C)
        if np.shape(self.T_SC) != (n, 4, 4):
            raise ValueError(f"T_SC must be ({n},4,4), got {np.shape(self.T_SC)}")
        same = len(self.image) == len(self.conf) == len(self.grey) == p
        if np.shape(self.points_C) != (p, 3) or not same:
            raise ValueError("points_C (P,3), image, conf and grey (P,) must have one row per point")
        if not 0 <= self.centre < n:
            raise ValueError(f"centre {self.centre} outside 0..{n - 1}")

    @property
    def n_points(self) -> int:
        return int(len(self.points_C))

    def state(self) -> SubmapState:
        """Its graph state without the points (a copy)."""
        return SubmapState(self.index, self.frame_t_ns.copy(), self.centre, self.T_OS.copy(),
                           np.array(self.T_MS, np.float64), float(self.lam), self.version, self.segment,
                           dict(self.fit), self.n_points)

    def points_S(self) -> np.ndarray:
        """(P,3) points in the submap frame S_j with the current lambda (metres)."""
        return place_points(self.points_C, self.image, self.T_SC, np.eye(4), self.lam)

    def points_M(self) -> np.ndarray:
        """(P,3) points in the map frame with the current graph state (eq. placement)."""
        return place_points(self.points_C, self.image, self.T_SC, self.T_MS, self.lam)
