"""Keyframes at a fixed sensor-time spacing during tracking, grouped into overlapping windows
(paper Sec. III: five frames at 0.5 s keyframe spacing, two images shared between consecutive
windows), and the bounded queue that drops the oldest pending window when the model worker is busy."""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from runtime.events import Frame
from runtime.mapping.config import MappingConfig


@dataclass
class MappingWindow:
    """One mapping window.

    Attributes:
        window_id: running number of the window (0, 1, ...), dropped windows included.
        frames: the keyframes (camera images as delivered, distorted).
        T_OC: (N,4,4) the filter's metric camera poses T_OC_i at the frames (odometry frame O).
        segment: filter segment (a restart after a divergence starts a new odometry frame).
    """

    window_id: int
    frames: list[Frame]
    T_OC: np.ndarray
    segment: int

    @property
    def t_ns(self) -> np.ndarray:
        return np.array([int(f.t_ns) for f in self.frames], np.int64)


class WindowBuilder:
    """Selects keyframes from published camera poses and emits a window every
    `window_images - shared_images` keyframes once `window_images` are collected."""

    def __init__(self, cfg: MappingConfig | None = None) -> None:
        self.cfg = cfg or MappingConfig()
        if not 0 <= self.cfg.shared_images < self.cfg.window_images:
            raise ValueError("shared_images must be in [0, window_images)")
        if self.cfg.window_images < 2:
            raise ValueError("a mapping window needs at least 2 images")
        self._keyframes: list[tuple[Frame, np.ndarray]] = []
        self._segment: int | None = None
        self._last_ns: int | None = None
        self._next_id = 0
        # a keyframe is due when at least this much sensor time passed (2 % slack for stamp jitter)
        self._spacing_ns = int(round(0.98 * self.cfg.keyframe_spacing_s * 1e9))
        self.keyframes = 0

    def add(self, frame: Frame, T_OC: np.ndarray, segment: int = 0) -> MappingWindow | None:
        """Offer a tracked frame with its published camera pose; returns a window when one is complete."""
        if self._segment is not None and segment != self._segment:
            self._keyframes.clear()       # a new odometry frame: windows never straddle it
            self._last_ns = None
        self._segment = segment
        t = int(frame.t_ns)
        if self._last_ns is not None and t - self._last_ns < self._spacing_ns:
            return None
        self._last_ns = t
        self.keyframes += 1
        self._keyframes.append((frame, np.asarray(T_OC, np.float64).copy()))
        n = self.cfg.window_images
        if len(self._keyframes) < n:
            return None
        kfs = self._keyframes[-n:]
        self._keyframes = self._keyframes[len(self._keyframes) - self.cfg.shared_images:] \
            if self.cfg.shared_images else []
        w = MappingWindow(self._next_id, [f for f, _ in kfs], np.stack([T for _, T in kfs]), segment)
        self._next_id += 1
        return w


class WindowQueue:
    """Bounded queue of pending windows; when full, the oldest pending window is dropped and counted."""

    def __init__(self, maxlen: int) -> None:
        if maxlen < 1:
            raise ValueError(f"the mapping queue needs room for at least one window, got {maxlen}")
        self.maxlen = int(maxlen)
        self._q: deque[MappingWindow] = deque()
        self.dropped: list[int] = []

    def __len__(self) -> int:
        return len(self._q)

    def put(self, w: MappingWindow) -> MappingWindow | None:
        """Enqueue; returns the dropped (oldest) window when the queue was full."""
        dropped = None
        if len(self._q) >= self.maxlen:
            dropped = self._q.popleft()
            self.dropped.append(dropped.window_id)
        self._q.append(w)
        return dropped

    def pop(self) -> MappingWindow | None:
        return self._q.popleft() if self._q else None
