"""Inputs of `davio bench mapping`: one tracking run and the keyframe windows every mapper variant gets.

The recording is tracked once by the pipeline with the native initializer only and mapping off
(no depth model). The published poses then go through the pipeline's own keyframe selector
(`WindowBuilder`, the frame's published pose T_OC = T_OI T_IC, as VioPipeline offers them), so the
windows are the ones a live run would queue. The same windows are also built with the true camera
poses (T_WC of the frame stamps). Only the longest published segment is used (a filter restart
opens a new odometry frame). The VIO trajectory of that segment is aligned rigidly (SE(3), no
scale) to the ground truth; the same transform places VIO-pose maps in the world frame.
"""
from __future__ import annotations

import time
from collections import OrderedDict
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from runtime.mapping.config import MappingConfig
from runtime.mapping.windows import MappingWindow, WindowBuilder


@dataclass
class MappingInputs:
    """What every mapper variant of one sequence is given, and the VIO-to-world alignment.

    Attributes:
        windows: the keyframe windows with the VIO camera poses T_OC (odometry frame).
        windows_gt: the same frames with the true camera poses T_WC (world frame).
        R_WO, t_WO: SE(3) alignment of the VIO trajectory to the ground truth (x_W = R x_O + t).
        vio_ate_m: ATE (SE(3)) of the aligned segment, metres.
        published: published poses of the run; segments: published segments.
        frames: frames tracked; tracking_s: wall time of the tracking run (rendering included).
    """

    windows: list[MappingWindow]
    windows_gt: list[MappingWindow]
    R_WO: np.ndarray
    t_WO: np.ndarray
    vio_ate_m: float
    published: int
    segments: int
    frames: int
    tracking_s: float

    @property
    def keyframe_t_ns(self) -> np.ndarray:
        """Sorted unique camera stamps of the windows' frames."""
        if not self.windows:
            return np.zeros(0, np.int64)
        return np.unique(np.concatenate([w.t_ns for w in self.windows]))

    def to_world(self, points_O: np.ndarray) -> np.ndarray:
        """(P,3) odometry-frame points in the world frame (the trajectory alignment)."""
        return np.asarray(points_O, np.float64) @ self.R_WO.T + self.t_WO


class _FrameKeeper:
    """A driver that passes a recording's events through and keeps its frames by stamp."""

    def __init__(self, rec: Any) -> None:
        self.rec = rec
        self.rig = rec.rig
        self.frames: dict[int, Any] = {}

    def events(self):
        for ev in self.rec.events():
            if hasattr(ev, "image"):
                self.frames[int(ev.t_ns)] = ev
            yield ev


def track(rec: Any, mapping: MappingConfig | None = None) -> MappingInputs:
    """Track `rec` (a SimRecording) natively with mapping off and build the windows (module docstring).

    Raises:
        DataError: no published segment long enough to align (fewer than 3 poses).
    """
    from runtime.config import DavioConfig
    from runtime.errors import DataError
    from tools.evaluation import ate
    from tools.run_io import published_segments, published_trajectory
    from tools.run_session import run_pipeline

    mapping = mapping or MappingConfig()
    base = DavioConfig()
    config = replace(base, mapping=replace(mapping, enabled=False))
    keeper = _FrameKeeper(rec)
    t0 = time.perf_counter()
    res = run_pipeline(keeper, None, config, show_progress=False)
    tracking_s = time.perf_counter() - t0
    published = list(res.pipeline.published)
    segments = published_segments(published)
    if not segments or max(len(s) for s in segments) < 3:
        raise DataError(f"the tracking run published {len(published)} poses: nothing to map",
                        rec.info.get("source"))
    seg = max(segments, key=len)
    result = ate(published_trajectory(seg), rec.groundtruth(), align_method="se3")
    T_IC = np.asarray(rec.rig.T_IC, np.float64)
    # the pose each frame published (the last one stamped with that camera time), in frame order
    by_frame: OrderedDict[int, Any] = OrderedDict()
    for p in seg:
        by_frame[int(p.t_cam_ns)] = p
    builder = WindowBuilder(mapping)
    windows = []
    for t_cam in sorted(by_frame):
        p = by_frame[t_cam]
        frame = keeper.frames.get(t_cam)
        if frame is None:
            continue
        w = builder.add(frame, p.T_OI @ T_IC, p.segment)
        if w is not None:
            windows.append(w)
    n_frames = len(keeper.frames)
    keeper.frames.clear()           # the windows keep their keyframes
    truth = rec.gt_source
    windows_gt = [MappingWindow(w.window_id, w.frames,
                                np.stack([truth.camera_pose(int(t)) for t in w.t_ns]), w.segment)
                  for w in windows]
    return MappingInputs(windows, windows_gt, result.alignment.R, result.alignment.t,
                         float(result.trans["rmse"]), len(published), len(segments),
                         n_frames, tracking_s)


class CachedTruth:
    """A ground-truth source whose rendered views are kept (all variants map the same frames).

    Args:
        source: the recording's ground truth (`render_view`, `camera_pose`).
    """

    def __init__(self, source: Any) -> None:
        self.source = source
        self._views: dict[tuple, Any] = {}

    def render_view(self, t_ns: int, K: np.ndarray, width: int, height: int) -> Any:
        key = (int(t_ns), np.asarray(K, np.float64).tobytes(), int(width), int(height))
        view = self._views.get(key)
        if view is None:
            view = self._views[key] = self.source.render_view(t_ns, K, width, height)
        return view

    def camera_pose(self, t_ns: int) -> np.ndarray:
        return self.source.camera_pose(t_ns)


class SharedMatcher:
    """A matcher shared by the mapper variants: features and matches computed once per image content
    and image pair (identical results; the variants map the same frames).

    Args:
        matcher: a models.matcher.Matcher.
    """

    def __init__(self, matcher: Any) -> None:
        self.matcher = matcher
        self.backend = getattr(matcher, "backend", "")
        self._features: dict[bytes, Any] = {}
        self._matches: dict[tuple[bytes, bytes], Any] = {}

    @staticmethod
    def _key(img: np.ndarray, extra: str = "") -> bytes:
        import hashlib

        digest = hashlib.blake2b(img.tobytes(), digest_size=16).digest()
        return digest + bytes(str(img.shape) + extra, "ascii")

    def detect(self, image: np.ndarray) -> Any:
        img = np.ascontiguousarray(image)
        key = self._key(img)
        f = self._features.get(key)
        if f is None:
            f = self._features[key] = self.matcher.detect(img)
        return f

    def detect_pyramid(self, image: np.ndarray, scales: Any, base: Any = None) -> Any:
        img = np.ascontiguousarray(image)
        key = self._key(img, repr(tuple(scales)))
        f = self._features.get(key)
        if f is None:
            f = self._features[key] = self.matcher.detect_pyramid(img, scales, base)
        return f

    @staticmethod
    def _feature_key(f: Any) -> bytes:
        """Content key of a feature set: archived views come back as a new object on every
        `ViewStore.get`, so an id() may be reused by another view's features."""
        import hashlib

        h = hashlib.blake2b(digest_size=16)
        for a in (f.kpts, f.desc, getattr(f, "level", None)):
            if a is not None:
                arr = np.ascontiguousarray(a)
                h.update(arr.tobytes())
                h.update(str((arr.dtype, arr.shape)).encode())
        return h.digest()

    def match_features(self, fa: Any, fb: Any) -> Any:
        key = (self._feature_key(fa), self._feature_key(fb))
        m = self._matches.get(key)
        if m is None:
            m = self._matches[key] = self.matcher.match_features(fa, fb)
        return m
