"""KLT feature tracker for the MSCKF front-end (OpenVINS ``TrackKLT`` style).

Per frame: histogram equalisation, pyramidal Lucas-Kanade from the previous frame with a
forward-backward consistency check (ours; OpenVINS has none), fundamental-matrix RANSAC on
undistorted normalized coordinates between consecutive frames (FM_RANSAC at 2 px, as OpenVINS),
then, once enough tracks are missing (OpenVINS' rule), FAST corners in the grid cells holding fewer
tracks than their share (OpenVINS: half of it, ``detect_cell_fraction``) to top the tracks up to
``num_pts`` while keeping ``min_px_dist`` from existing tracks.

Pixels are distorted image pixels (u, v), (0, 0) at the centre of the top-left pixel (OpenCV);
``xy`` are undistorted normalized coordinates (X/Z, Y/Z) through the rig's camera model.
Bad frames (too dark, frozen = identical to the previous one, not after the previous frame in
time) are counted and answered with an empty result; the tracker keeps its last good image and
resumes from it on the next good frame. A wrong image size or type raises DataError.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import cv2
import numpy as np

from runtime.config_checks import at_least, finite_fields, in_range, non_negative, positive
from runtime.errors import ConfigError, DataError
from runtime.msckf.corner_grid import block_neighbourhoods, choose_corners

if TYPE_CHECKING:
    from calib import CameraModel
    from runtime.events import Frame

_EQUALIZATIONS = ("histogram", "clahe", "none")
_RANSAC_METHODS = {"magsac": cv2.USAC_MAGSAC, "ransac": cv2.FM_RANSAC}
_FAST_MARGIN_PX = 4
"""FAST's 3 px scoring circle plus the 1 px of its non-maximum suppression."""


@dataclass
class TrackerConfig:
    """KLT tracker settings; defaults follow OpenVINS' EuRoC configuration where it has one."""

    num_pts: int = 200
    """Target number of tracked features per frame (OpenVINS EuRoC num_pts)."""
    grid_x: int = 5
    """Detection grid columns (OpenVINS EuRoC grid_x)."""
    grid_y: int = 5
    """Detection grid rows (OpenVINS EuRoC grid_y)."""
    min_px_dist: float = 10.0
    """Minimum pixel distance between features (OpenVINS EuRoC min_px_dist), px."""
    fast_threshold: int = 20
    """FAST intensity threshold (OpenVINS EuRoC fast_threshold)."""
    fast_threshold_min: int = 5
    """Lower FAST threshold retried in grid cells where fast_threshold finds nothing."""
    min_new_features: int = 20
    """Corners are detected only once at least min(this, num_pts / 2) tracks are missing (OpenVINS
    TrackKLT: 20); 1 tops up every frame."""
    detect_cell_fraction: float = 1.0
    """FAST runs only in grid cells holding fewer tracks than max(1, int(this x share)), share =
    ceil(num_pts / cells) (OpenVINS TrackKLT: 0.5; 1.0: every cell below its share)."""
    pyramid_levels: int = 5
    """Pyramid levels above the base image for LK (OpenVINS TrackKLT pyr_levels = 5)."""
    window_px: int = 15
    """LK window side, px (OpenVINS TrackKLT win_size 15x15)."""
    lk_max_iterations: int = 30
    """LK iterations per level."""
    lk_epsilon: float = 0.01
    """LK convergence threshold, px."""
    fb_check_px: float = 1.0
    """Forward-backward check: reject a track whose round trip misses its start by more, px (<= 0: off)."""
    ransac: bool = True
    """Reject outliers with a fundamental-matrix RANSAC between consecutive frames."""
    ransac_method: str = "ransac"
    """'ransac' (OpenCV FM_RANSAC, as OpenVINS) or 'magsac' (USAC_MAGSAC: about 14x the time per frame,
    accuracy within the seed spread, BENCHMARKS.md "Tracking pipeline and filter cost")."""
    ransac_threshold_px: float = 2.0
    """RANSAC epipolar threshold in pixels, divided by the focal length on normalized points (OpenVINS: 2)."""
    ransac_confidence: float = 0.999
    """RANSAC confidence."""
    ransac_min_points: int = 10
    """Fewer tracks than this skip RANSAC (counted as ransac_skipped)."""
    equalization: str = "histogram"
    """Contrast normalisation before tracking: 'histogram', 'clahe' or 'none' (OpenVINS: histogram)."""
    clahe_clip_limit: float = 10.0
    """CLAHE clip limit (OpenVINS 10)."""
    clahe_tiles: int = 8
    """CLAHE tile grid side (OpenVINS 8x8)."""
    border_px: int = 5
    """Tracks closer than this to the image border are dropped and no corner is detected there, px."""
    dark_mean_max: float = 10.0
    """A frame whose mean intensity (0..255) is below this counts as dark and is skipped."""
    dark_std_min: float = 2.0
    """A frame whose intensity std is below this (featureless/saturated) counts as dark and is skipped."""

    def __post_init__(self) -> None:
        finite_fields(self, "tracker")
        positive(self, "tracker", "ransac_threshold_px")
        in_range(self, "tracker", "ransac_confidence", 0.0, 1.0, lo_open=True)
        non_negative(self, "tracker", "lk_epsilon", "clahe_clip_limit", "dark_mean_max", "dark_std_min")
        if self.num_pts < 1:
            raise ConfigError(f"tracker.num_pts must be >= 1, got {self.num_pts}")
        if self.grid_x < 1 or self.grid_y < 1:
            raise ConfigError(f"tracker grid must be >= 1x1, got {self.grid_x}x{self.grid_y}")
        if self.window_px < 3 or self.window_px % 2 == 0:
            raise ConfigError(f"tracker.window_px must be an odd number >= 3, got {self.window_px}")
        if self.pyramid_levels < 0:
            raise ConfigError(f"tracker.pyramid_levels must be >= 0, got {self.pyramid_levels}")
        if not 0.0 < self.detect_cell_fraction <= 1.0:
            raise ConfigError(
                f"tracker.detect_cell_fraction must be in (0, 1], got {self.detect_cell_fraction}")
        if self.min_new_features < 1:
            raise ConfigError(f"tracker.min_new_features must be >= 1, got {self.min_new_features}")
        if self.min_px_dist < 0:
            raise ConfigError(f"tracker.min_px_dist must be >= 0, got {self.min_px_dist}")
        if self.equalization not in _EQUALIZATIONS:
            raise ConfigError(
                f"tracker.equalization must be one of {_EQUALIZATIONS}, got {self.equalization!r}")
        if self.ransac_method not in _RANSAC_METHODS:
            raise ConfigError(
                f"tracker.ransac_method must be one of {tuple(_RANSAC_METHODS)}, got {self.ransac_method!r}")
        if self.ransac_threshold_px <= 0:
            raise ConfigError(f"tracker.ransac_threshold_px must be > 0, got {self.ransac_threshold_px}")
        if self.ransac_min_points < 8:
            raise ConfigError(f"tracker.ransac_min_points must be >= 8, got {self.ransac_min_points}")
        # OpenCV divides by the CLAHE grid (0 kills the process with SIGFPE); the others are counts and
        # sizes a negative value (or no LK iteration) makes meaningless
        at_least(self, "tracker", 1, "clahe_tiles", "lk_max_iterations")
        at_least(self, "tracker", 0, "border_px", "fast_threshold", "fast_threshold_min")


@dataclass
class TrackResult:
    """Tracks at one frame.

    Attributes:
        t_ns: frame time (camera clock), int64 ns.
        ids: (M,) int64 persistent feature ids (a new id for every new corner, never reused).
        uv: (M, 2) float64 distorted pixels.
        xy: (M, 2) float64 undistorted normalized coordinates (X/Z, Y/Z) in the camera frame.
        stats: per-frame counters: n_tracked (kept from the previous frame), n_new (detected),
            n_lk_failed, n_fb_rejected, n_border_rejected, n_ransac_rejected, n_undistort_failed,
            ransac_skipped, dark, frozen, out_of_order (bool flags; such a frame returns no tracks
            and tracking resumes from the last good frame).
    """

    t_ns: int
    ids: np.ndarray
    uv: np.ndarray
    xy: np.ndarray
    stats: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.ids.shape[0])


class KltTracker:
    """Pyramidal-LK tracker with FAST-on-grid detection for one camera.

    Args:
        camera: the camera model (image size, intrinsics, distortion) of the frames fed.
        config: tracker settings (TrackerConfig() if None).
    """

    def __init__(self, camera: CameraModel, config: TrackerConfig | None = None) -> None:
        self.camera = camera
        self.config = config if config is not None else TrackerConfig()
        self._fast = cv2.FastFeatureDetector_create(threshold=int(self.config.fast_threshold),
                                                    nonmaxSuppression=True)
        self._fast_low = cv2.FastFeatureDetector_create(threshold=int(self.config.fast_threshold_min),
                                                        nonmaxSuppression=True)
        self._clahe = None
        if self.config.equalization == "clahe":
            tiles = int(self.config.clahe_tiles)
            self._clahe = cv2.createCLAHE(clipLimit=float(self.config.clahe_clip_limit),
                                          tileGridSize=(tiles, tiles))
        self._prev_raw: np.ndarray | None = None  # last good raw image (for the frozen check)
        self._prev_img: np.ndarray | None = None  # last good equalised image
        self._prev_ids = np.zeros(0, dtype=np.int64)
        self._prev_uv = np.zeros((0, 2), dtype=np.float64)
        self._prev_xy = np.zeros((0, 2), dtype=np.float64)
        self._prev_t_ns: int | None = None
        self._next_id = 0
        self._warm_kernels()
        self.counters = {
            "frames": 0, "dark_frames": 0, "frozen_frames": 0, "non_monotonic_frames": 0,
            "lk_failed": 0, "fb_rejected": 0, "border_rejected": 0, "ransac_rejected": 0,
            "undistort_failed": 0, "ransac_skipped": 0, "new_features": 0,
        }

    # ------------------------------------------------------------------ public
    def report(self) -> dict:
        """Cumulative counters since construction (for the run report)."""
        return dict(self.counters)

    def reset(self) -> None:
        """Forget all tracks and the previous image (ids keep increasing)."""
        self._prev_raw = None
        self._prev_img = None
        self._prev_t_ns = None
        self._set_prev(np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2)))

    def track(self, frame: Frame) -> TrackResult:
        """Track the previous frame's features into ``frame`` and top up with new corners.

        Raises:
            DataError: the image is not a 2-D uint8 array of the camera's size.
        """
        image = self._check_image(frame)
        cfg = self.config
        t_ns = int(frame.t_ns)
        self.counters["frames"] += 1
        stats = {"n_tracked": 0, "n_new": 0, "n_lk_failed": 0, "n_fb_rejected": 0, "n_border_rejected": 0,
                 "n_ransac_rejected": 0, "n_undistort_failed": 0, "ransac_skipped": False,
                 "dark": False, "frozen": False, "out_of_order": False}
        if self._prev_t_ns is not None and t_ns <= self._prev_t_ns:
            stats["out_of_order"] = True
            self.counters["non_monotonic_frames"] += 1
            return self._empty(t_ns, stats)

        mean, std = cv2.meanStdDev(image)
        if float(mean[0, 0]) < cfg.dark_mean_max or float(std[0, 0]) < cfg.dark_std_min:
            stats["dark"] = True
            self.counters["dark_frames"] += 1
            return self._empty(t_ns, stats)
        if self._prev_raw is not None and np.array_equal(image, self._prev_raw):
            stats["frozen"] = True
            self.counters["frozen_frames"] += 1
            return self._empty(t_ns, stats)

        img = self._equalize(image)
        rows, uv = self._track_from_previous(img, stats)
        xy = self.camera.undistort_points(uv) if uv.shape[0] else np.zeros((0, 2))
        ok = np.all(np.isfinite(xy), axis=1)
        stats["n_undistort_failed"] = int((~ok).sum())
        rows, uv, xy = rows[ok], uv[ok], xy[ok]
        ids, prev_xy = self._prev_ids[rows], self._prev_xy[rows]
        if cfg.ransac and uv.shape[0] > 0:
            keep = self._ransac(prev_xy, xy, stats)
            ids, uv, xy = ids[keep], uv[keep], xy[keep]
        stats["n_tracked"] = int(ids.shape[0])

        new_uv = self._detect(img, uv, cfg.num_pts - uv.shape[0])
        if new_uv.shape[0]:
            new_xy = self.camera.undistort_points(new_uv)
            good = np.all(np.isfinite(new_xy), axis=1)
            new_uv, new_xy = new_uv[good], new_xy[good]
            new_ids = np.arange(self._next_id, self._next_id + new_uv.shape[0], dtype=np.int64)
            self._next_id += new_uv.shape[0]
            ids = np.concatenate([ids, new_ids])
            uv = np.concatenate([uv, new_uv])
            xy = np.concatenate([xy, new_xy])
            stats["n_new"] = int(new_uv.shape[0])

        for key in ("lk_failed", "fb_rejected", "border_rejected", "ransac_rejected", "undistort_failed"):
            self.counters[key] += stats["n_" + key]
        self.counters["ransac_skipped"] += int(stats["ransac_skipped"])
        self.counters["new_features"] += stats["n_new"]
        self._prev_raw = image.copy()
        self._prev_img = img
        self._prev_t_ns = t_ns
        self._set_prev(ids, uv, xy)
        return TrackResult(t_ns, ids.copy(), uv.copy(), xy.copy(), stats)

    # ------------------------------------------------------------------ steps
    def _warm_kernels(self) -> None:
        """Load the detection and undistortion kernels (numba) now rather than in the first frame."""
        occupied = np.zeros((3, 3), dtype=bool)
        uv = np.ones((1, 2))
        block_neighbourhoods(occupied, uv, 1.0)
        choose_corners(uv, occupied, np.zeros((1, 1), dtype=np.int64), 1, 1, 1.0, 3, 3)
        self.camera.undistort_points(np.array([[self.camera.cx, self.camera.cy]], dtype=np.float64))

    def _check_image(self, frame: Frame) -> np.ndarray:
        image = np.asarray(frame.image)
        if image.ndim != 2 or image.dtype != np.uint8:
            raise DataError(f"frame at {frame.t_ns} ns: expected a 2-D uint8 grey image, got "
                            f"{image.dtype} with shape {image.shape}")
        if image.shape != (self.camera.height, self.camera.width):
            raise DataError(f"frame at {frame.t_ns} ns: image is {image.shape[1]}x{image.shape[0]} but the "
                            f"camera calibration is {self.camera.width}x{self.camera.height}")
        return np.ascontiguousarray(image)

    def _equalize(self, image: np.ndarray) -> np.ndarray:
        if self.config.equalization == "histogram":
            return cv2.equalizeHist(image)
        if self._clahe is not None:
            return self._clahe.apply(image)
        return image

    def _track_from_previous(self, img: np.ndarray, stats: dict) -> tuple[np.ndarray, np.ndarray]:
        """Rows of the previous frame's tracks that were followed into ``img``, and their pixels there."""
        cfg = self.config
        if self._prev_img is None or self._prev_uv.shape[0] == 0:
            return np.zeros(0, np.int64), np.zeros((0, 2))
        p0 = self._prev_uv.astype(np.float32).reshape(-1, 1, 2)
        win = (cfg.window_px, cfg.window_px)
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, cfg.lk_max_iterations, cfg.lk_epsilon)
        p1, st1, _ = cv2.calcOpticalFlowPyrLK(self._prev_img, img, p0, None, winSize=win,
                                              maxLevel=cfg.pyramid_levels, criteria=crit)
        ok = st1.reshape(-1).astype(bool) & np.all(np.isfinite(p1.reshape(-1, 2)), axis=1)
        if cfg.fb_check_px > 0:
            p0b, st0, _ = cv2.calcOpticalFlowPyrLK(img, self._prev_img, p1, p0.copy(), winSize=win,
                                                   maxLevel=cfg.pyramid_levels, criteria=crit,
                                                   flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
            ok_back = st0.reshape(-1).astype(bool)
            stats["n_lk_failed"] = int((~(ok & ok_back)).sum())
            fb_err = np.linalg.norm(p0b.reshape(-1, 2) - p0.reshape(-1, 2), axis=1)
            fb_bad = ok & ok_back & ~(fb_err <= cfg.fb_check_px)
            stats["n_fb_rejected"] = int(fb_bad.sum())
            ok = ok & ok_back & ~fb_bad
        else:
            stats["n_lk_failed"] = int((~ok).sum())
        uv = p1.reshape(-1, 2).astype(np.float64)
        h, w = img.shape
        b = cfg.border_px
        inside = (uv[:, 0] >= b) & (uv[:, 0] <= w - 1 - b) & (uv[:, 1] >= b) & (uv[:, 1] <= h - 1 - b)
        stats["n_border_rejected"] = int((ok & ~inside).sum())
        keep = ok & inside
        return np.flatnonzero(keep), uv[keep]

    def _ransac(self, xy0: np.ndarray, xy1: np.ndarray, stats: dict) -> np.ndarray:
        cfg = self.config
        n = xy0.shape[0]
        keep = np.ones(n, dtype=bool)
        if n < cfg.ransac_min_points:
            stats["ransac_skipped"] = True
            return keep
        f = 0.5 * (self.camera.fx + self.camera.fy)
        _, mask = cv2.findFundamentalMat(xy0.astype(np.float64), xy1.astype(np.float64),
                                         _RANSAC_METHODS[cfg.ransac_method],
                                         cfg.ransac_threshold_px / f, cfg.ransac_confidence, 1000)
        if mask is None or mask.shape[0] != n:
            # degenerate configuration (no F could be fit): keep everything, say so
            stats["ransac_skipped"] = True
            return keep
        keep = mask.reshape(-1).astype(bool)
        stats["n_ransac_rejected"] = int((~keep).sum())
        return keep

    def _detect(self, img: np.ndarray, existing_uv: np.ndarray, n_wanted: int) -> np.ndarray:
        """New corners (K, 2) on a grid, at least min_px_dist from existing and other new ones.

        As OpenVINS' TrackKLT: nothing is detected while fewer than min(min_new_features, num_pts / 2)
        tracks are missing, and FAST runs only in the grid cells that hold fewer tracks than
        detect_cell_fraction of their quota (OpenVINS: 0.5, ours 1.0).
        """
        cfg = self.config
        if n_wanted <= 0 or n_wanted < min(cfg.min_new_features, cfg.num_pts // 2):
            return np.zeros((0, 2))
        h, w = img.shape
        b = cfg.border_px
        cell = max(cfg.min_px_dist, 1.0)
        occ_w, occ_h = int(np.ceil(w / cell)) + 1, int(np.ceil(h / cell)) + 1
        occupied = np.zeros((occ_h, occ_w), dtype=bool)
        # existing features block their min_px_dist neighbourhood (occupancy cells of that size)
        block_neighbourhoods(occupied, np.ascontiguousarray(existing_uv, dtype=np.float64), float(cell))
        # per-grid-cell quota so corners spread over the image
        gx = np.clip((existing_uv[:, 0] * cfg.grid_x / w).astype(int), 0, cfg.grid_x - 1)
        gy = np.clip((existing_uv[:, 1] * cfg.grid_y / h).astype(int), 0, cfg.grid_y - 1)
        count = np.zeros((cfg.grid_y, cfg.grid_x), dtype=int)
        np.add.at(count, (gy, gx), 1)
        quota_per_cell = int(np.ceil(cfg.num_pts / (cfg.grid_x * cfg.grid_y)))
        found = []
        detect_below = max(1, int(cfg.detect_cell_fraction * quota_per_cell))
        for r, c in np.argwhere(count < detect_below):
            # the cell inside the border
            y0, y1 = max(int(r * h / cfg.grid_y), b), min(int((r + 1) * h / cfg.grid_y), h - b)
            x0, x1 = max(int(c * w / cfg.grid_x), b), min(int((c + 1) * w / cfg.grid_x), w - b)
            if y1 - y0 < 1 or x1 - x0 < 1:
                continue
            pts_cell = self._fast_in(img, self._fast, x0, x1, y0, y1)
            if pts_cell.shape[0] == 0 and cfg.fast_threshold_min < cfg.fast_threshold:
                # a cell where the normal threshold finds nothing gets a second chance at the lower one
                pts_cell = self._fast_in(img, self._fast_low, x0, x1, y0, y1)
            found.append(pts_cell)
        pts = np.concatenate(found) if found else np.zeros((0, 3))
        if pts.shape[0] == 0:
            return np.zeros((0, 2))
        # drop corners next to existing tracks at once, keep the strongest few per wanted corner
        free = ~occupied[(pts[:, 1] / cell).astype(int), (pts[:, 0] / cell).astype(int)]
        pts = pts[free]
        order = np.argsort(-pts[:, 2], kind="stable")[: max(64, 30 * n_wanted)]
        pts = pts[order]
        rows = choose_corners(np.ascontiguousarray(pts[:, :2]), occupied, count, quota_per_cell,
                              int(n_wanted), float(cell), w, h)
        if rows.shape[0] == 0:
            return np.zeros((0, 2))
        uv = pts[rows, :2].astype(np.float32).reshape(-1, 1, 2)
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 0.01)
        cv2.cornerSubPix(img, uv, (3, 3), (-1, -1), crit)
        return uv.reshape(-1, 2).astype(np.float64)

    @staticmethod
    def _fast_in(img: np.ndarray, detector: cv2.FastFeatureDetector, x0: int, x1: int, y0: int,
                 y1: int) -> np.ndarray:
        """(K, 3) pixel u, v and FAST response of the corners `detector` finds in the image whose pixels lie
        in [x0, x1) x [y0, y1): the corners FAST finds on the whole image there.

        FAST scores a pixel from the 3 px circle around it and non-maximum suppression compares it with its
        8 neighbours, so the view it runs on reaches 4 px beyond the cell (where the image has them)."""
        h, w = img.shape
        rx0, ry0 = max(x0 - _FAST_MARGIN_PX, 0), max(y0 - _FAST_MARGIN_PX, 0)
        view = img[ry0:min(y1 + _FAST_MARGIN_PX, h), rx0:min(x1 + _FAST_MARGIN_PX, w)]
        kps = detector.detect(view, None)
        if not kps:
            return np.zeros((0, 3))
        uv = cv2.KeyPoint_convert(kps).astype(np.float64).reshape(-1, 2) + (rx0, ry0)
        response = np.fromiter((k.response for k in kps), dtype=np.float64, count=len(kps))
        inside = (uv[:, 0] >= x0) & (uv[:, 0] < x1) & (uv[:, 1] >= y0) & (uv[:, 1] < y1)
        return np.column_stack([uv, response])[inside]

    def _set_prev(self, ids: np.ndarray, uv: np.ndarray, xy: np.ndarray) -> None:
        self._prev_ids, self._prev_uv, self._prev_xy = ids, uv, xy

    def _empty(self, t_ns: int, stats: dict) -> TrackResult:
        return TrackResult(t_ns, np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2)), stats)
